"""Direction-of-arrival estimation on antenna arrays (seed 003): MUSIC."""

from attopt.solvers.doa.music import DoaEstimates, MusicEstimator

__all__ = ["DoaEstimates", "MusicEstimator"]
