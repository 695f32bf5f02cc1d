"""The chi-square tail probability shared by every consistency and residual test.

``P(chi2(dof) >= statistic)``: the false-alarm side of the innovation window tests
(:func:`attopt.solvers.sequential.inconsistent_epochs`, the online
:class:`~attopt.solvers.sequential.TrackMonitor`, the manoeuvre detector of
:mod:`attopt.solvers.geo.manoeuvre`) and of the snapshot residual tests
(:func:`attopt.solvers.snapshot_sequence.residual_test`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import chdtrc


def chi_square_tail(statistic: ArrayLike, dof: ArrayLike) -> np.ndarray | float:
    """``P(chi2(dof) >= statistic)``, elementwise (the survival function).

    The same numbers as ``scipy.stats.chi2.sf(statistic, dof)``, which calls this
    special function after validating its arguments; called directly because the
    sequential estimators evaluate it once per update, where that validation costs
    about 90 us a call.  Callers pass ``dof > 0``; NaN in either argument gives NaN.

    Example::

        >>> from attopt.solvers.chi_square import chi_square_tail
        >>> round(float(chi_square_tail(7.815, 3)), 4)
        0.05
    """
    return chdtrc(dof, statistic)
