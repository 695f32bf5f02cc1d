"""Recursive filter baselines: MEKF, USQUE and the multiplicative RTS smoother."""

from attopt.solvers.filters.common import FilterHistory, FilterOptions, FilterPrior
from attopt.solvers.filters.mekf import mekf
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.filters.usque import usque

__all__ = [
    "FilterHistory",
    "FilterOptions",
    "FilterPrior",
    "mekf",
    "rts_smooth",
    "usque",
]
