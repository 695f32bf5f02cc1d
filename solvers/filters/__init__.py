"""Recursive filter baselines: MEKF, USQUE and the multiplicative RTS smoother."""

from solvers.filters.common import (
    FilterHistory,
    FilterOptions,
    FilterPrior,
    FilterResult,
)
from solvers.filters.mekf import mekf
from solvers.filters.rts import rts_smooth
from solvers.filters.usque import usque

__all__ = [
    "FilterHistory",
    "FilterOptions",
    "FilterPrior",
    "FilterResult",
    "mekf",
    "rts_smooth",
    "usque",
]
