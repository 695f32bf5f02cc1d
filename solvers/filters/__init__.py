"""Recursive filter baselines: the MEKF, USQUE and the multiplicative RTS smoother.

Registry estimators (:mod:`attopt.solvers.filters.estimators`): ``mekf``,
``usque`` and ``rts``, and ``mekf_offsets`` and ``usque_offsets`` with transmitter
power offsets (:mod:`attopt.solvers.filters.offsets`); their predict and update steps
are in
:mod:`attopt.solvers.filters.mekf` and :mod:`attopt.solvers.filters.usque`,
the loop that runs them in :mod:`attopt.solvers.sequential`.
"""

from attopt.solvers.filters.common import FilterOptions
from attopt.solvers.filters.estimators import Mekf, MekfOffsets, Rts, Usque, UsqueOffsets

ESTIMATORS = (Mekf(), Usque(), Rts(), MekfOffsets(), UsqueOffsets())
"""The package's registry estimators with their default options."""

__all__ = ["ESTIMATORS", "FilterOptions", "Mekf", "MekfOffsets", "Rts", "Usque", "UsqueOffsets"]
