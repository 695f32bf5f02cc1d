"""Whole-pass factor-graph smoother over attitude and gyro bias (GTSAM; ``docs/smoother.md``)."""

from attopt.solvers.smoother.batch import (
    SmootherOptions,
    SmootherProblem,
    SmootherReport,
    SmootherResult,
    single_frame_initial,
    smooth,
)
from attopt.solvers.smoother.online import OnlineOptions, OnlineReport, OnlineResult, smooth_online

__all__ = [
    "OnlineOptions",
    "OnlineReport",
    "OnlineResult",
    "SmootherOptions",
    "SmootherProblem",
    "SmootherReport",
    "SmootherResult",
    "single_frame_initial",
    "smooth",
    "smooth_online",
]
