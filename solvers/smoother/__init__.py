"""Whole-pass factor-graph smoother over attitude and gyro bias (GTSAM; ``docs/smoother.md``)."""

from solvers.smoother.batch import (
    SmootherOptions,
    SmootherProblem,
    SmootherReport,
    SmootherResult,
    smooth,
)

__all__ = ["SmootherOptions", "SmootherProblem", "SmootherReport", "SmootherResult", "smooth"]
