"""The offsets' elimination's rank update compiled with numba.

Eliminating a node, and the offsets of the aircraft that have set after it, subtracts
``U^T U`` from the dense block over the active offsets
(:mod:`attopt.solvers.smoother.offset_elimination`), ``U`` of 6 to about 10 rows and as
many columns as active offsets (up to 1,752 over the hour of ``adsb-snr``); it is most
of the elimination's time.  numpy forms ``U^T U`` in a temporary and subtracts it, three
passes over the block; :func:`downdate` makes one pass, in place, row by row.  Written
by hand, with numba, because BLAS's ``dsyrk`` updates in place only a whole contiguous
array, while the active block is the corner of a larger buffer whose size changes at
every node.  Measured at 1,750 active offsets and 6 rows: 4.0 ms against numpy's 8.3
ms (one thread).  The numpy expression remains the reference (``ATTOPT_KERNELS=
interpreted``, :data:`attopt.formulations.kernels.KERNELS_ENV`); the two agree to
round-off (``tests/test_offset_elimination.py``).  numba caches the machine code on disk
beside this module (``__pycache__``, or ``$NUMBA_CACHE_DIR``): the first use on a
machine compiles it (printed on standard error by
:func:`~attopt.formulations.kernels.report_compilation`).

Example::

    >>> import numpy as np
    >>> block = np.eye(3)
    >>> downdate(block, np.array([[1.0, 0.0, 0.0]]))
    >>> block.tolist()
    [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations.kernels import compiled_loops, first_call, register_warm_up

Array = NDArray[np.float64]


@njit(cache=True, error_model="numpy")
def _downdate(matrix: Array, update: Array, m: int) -> None:
    """``matrix[:m, :m] -= update^T update``, one row of ``matrix`` at a time."""
    for i in range(m):
        row = matrix[i]
        for q in range(update.shape[0]):
            a = update[q, i]
            u = update[q]
            for j in range(m):
                row[j] -= a * u[j]


def downdate(matrix: Array, update: Array) -> None:
    """``matrix[:m, :m] -= update^T update`` in place, ``m`` the columns of ``update``
    (``matrix`` a C-ordered buffer at least ``m x m``; module docstring)."""
    m = update.shape[1]
    if compiled_loops():
        update = np.ascontiguousarray(update, dtype=float)
        first_call(_downdate, "the offsets' elimination update", matrix, update, m)
    else:
        matrix[:m, :m] -= update.T @ update


register_warm_up("smoother.offsets_downdate", lambda: downdate(np.zeros((2, 2)), np.ones((1, 2))))
