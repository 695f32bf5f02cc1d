"""Factor-graph smoothers over attitude and gyro bias (GTSAM; ``docs/smoother.md``).

Registry estimators (:mod:`attopt.solvers.smoother.estimators`): ``fg_online``
(causal, :mod:`attopt.solvers.smoother.online`), ``fg_batch`` and
``fg_batch_offsets`` (whole pass, :mod:`attopt.solvers.smoother.batch`).
"""

from attopt.solvers.smoother.batch import SmootherReport
from attopt.solvers.smoother.estimators import (
    OFFSET_PRIOR_SIGMA_DB,
    BatchSmoother,
    OffsetBatchSmoother,
    OnlineSmoother,
)
from attopt.solvers.smoother.initial import single_frame_initial
from attopt.solvers.smoother.marginals import MarginalOptions
from attopt.solvers.smoother.online import OnlineOptions, OnlineReport
from attopt.solvers.smoother.optimiser_params import LevenbergMarquardtParams
from attopt.solvers.smoother.problem import GraphOptions, SmootherProblem

ESTIMATORS = (OnlineSmoother(), BatchSmoother(), OffsetBatchSmoother())
"""The package's registry estimators with their default options."""

__all__ = [
    "ESTIMATORS",
    "OFFSET_PRIOR_SIGMA_DB",
    "BatchSmoother",
    "GraphOptions",
    "LevenbergMarquardtParams",
    "MarginalOptions",
    "OffsetBatchSmoother",
    "OnlineOptions",
    "OnlineReport",
    "OnlineSmoother",
    "SmootherProblem",
    "SmootherReport",
    "single_frame_initial",
]
