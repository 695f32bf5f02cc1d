"""Whole-pass factor-graph smoother over attitude and gyro bias (GTSAM; ``docs/smoother.md``)."""

from solvers.smoother.batch import (
    SmootherOptions,
    SmootherProblem,
    SmootherReport,
    SmootherResult,
    smooth,
)
from solvers.smoother.online import OnlineOptions, OnlineReport, OnlineResult, smooth_online

__all__ = [
    "OnlineOptions",
    "OnlineReport",
    "OnlineResult",
    "SmootherOptions",
    "SmootherProblem",
    "SmootherReport",
    "SmootherResult",
    "smooth",
    "smooth_online",
]
