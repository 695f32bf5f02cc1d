"""Recursive filter baselines: the MEKF, USQUE and the multiplicative RTS smoother.

Registry estimators (:mod:`attopt.solvers.filters.estimators`): ``mekf``,
``usque`` and ``rts``; their predict and update steps are in
:mod:`attopt.solvers.filters.mekf` and :mod:`attopt.solvers.filters.usque`,
the loop that runs them in :mod:`attopt.solvers.sequential`.
"""

from attopt.solvers.filters.common import FilterOptions
from attopt.solvers.filters.estimators import Mekf, Rts, Usque

ESTIMATORS = (Mekf(), Usque(), Rts())
"""The package's registry estimators with their default options."""

__all__ = ["ESTIMATORS", "FilterOptions", "Mekf", "Rts", "Usque"]
