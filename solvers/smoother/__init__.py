"""Factor-graph smoothers over attitude and gyro bias (GTSAM; ``docs/smoother.md``).

Registry estimators (:mod:`attopt.solvers.smoother.estimators`): ``fg_online``.
The whole-pass batch smoother is :func:`~attopt.solvers.smoother.batch.smooth`.
"""

from attopt.solvers.smoother.batch import (
    SmootherOptions,
    SmootherProblem,
    SmootherReport,
    single_frame_initial,
    smooth,
)
from attopt.solvers.smoother.estimators import OnlineSmoother
from attopt.solvers.smoother.online import OnlineOptions, OnlineReport

ESTIMATORS = (OnlineSmoother(),)
"""The package's registry estimators with their default options."""

__all__ = [
    "ESTIMATORS",
    "OnlineOptions",
    "OnlineReport",
    "OnlineSmoother",
    "SmootherOptions",
    "SmootherProblem",
    "SmootherReport",
    "single_frame_initial",
    "smooth",
]
