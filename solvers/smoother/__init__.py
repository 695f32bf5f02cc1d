"""Whole-pass factor-graph smoother over attitude and gyro bias (GTSAM; ``docs/smoother.md``)."""

from attopt.solvers.smoother.batch import (
    SmootherOptions,
    SmootherProblem,
    SmootherReport,
    single_frame_initial,
    smooth,
)
from attopt.solvers.smoother.online import OnlineOptions, OnlineReport, smooth_online

__all__ = [
    "OnlineOptions",
    "OnlineReport",
    "SmootherOptions",
    "SmootherProblem",
    "SmootherReport",
    "single_frame_initial",
    "smooth",
    "smooth_online",
]
