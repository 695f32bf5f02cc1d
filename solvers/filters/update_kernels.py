"""The filters' per-update algebra compiled with numba: the gate, the gain, the reset.

At every epoch with a measurement the MEKF and USQUE (and the smoothers' gate) run a few
small computations on arrays of a handful of rows: each block's normalised innovation
for the gate (:func:`block_nis`), the information-form gain (:func:`information_gain`),
the error reset of one attitude or of the 13 sigma points (:func:`perturbed_quaternions`),
the smallest attitude variance that decides whether to iterate
(:func:`smallest_attitude_variance`), and whether the posterior is positive definite
(:func:`symmetric_positive`).  In numpy each is five to fifteen array calls, 20-60 us an
update for two unit vectors, more than the arithmetic; here each is one call of machine
code.  Written with numba for that per-call cost (CasADi's generated kernels cost more
per call than numpy, and the sizes vary from epoch to epoch).

The numpy functions stay the reference (``ATTOPT_KERNELS=interpreted``,
:func:`~attopt.formulations.kernels.compiled_loops`):
:func:`attopt.solvers.filters.common.block_nis_reference`,
:func:`~attopt.solvers.filters.common.gain_reference`,
:func:`~attopt.solvers.filters.common.perturbation_reference`,
:func:`~attopt.solvers.filters.common.linearised` and
:func:`~attopt.solvers.filters.common.repair_covariance` on that path.  The sums run
in another order than numpy's BLAS, so the two paths agree to round-off, not bit for
bit (``tests/test_update_kernels.py``: the normalised innovations within 1e-13 times
their block's condition number, relative; gains and posteriors within 1e-14 times the
posterior information's condition number, of their largest entry).  numba caches the machine code
on disk beside this module, as :mod:`attopt.solvers.filters.compiled`'s loops.

Example::

    >>> import numpy as np
    >>> gain, nis, posterior = information_gain(np.eye(2), np.eye(2), np.ones(2), np.ones(2))
    >>> np.diag(gain).tolist(), round(nis, 12), np.diag(posterior).tolist()  # equal halves
    ([0.5, 0.5], 1.0, [0.5, 0.5])
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations.kernels import first_call, register_warm_up
from attopt.solvers.filters.compiled import perturbed_into

Array = NDArray[np.float64]

_jit = njit(cache=True, error_model="numpy")
"""numba's compilation, cached on disk, with numpy's float semantics."""


def perturbed_quaternions(delta: Array, reference: Array) -> Array:
    """``(n, 4)``: each error vector of ``delta`` ``(n, 3)`` applied to ``reference``
    ``(n, 4)``, or to its one row ``(1, 4)``
    (:func:`attopt.solvers.filters.common.perturb_quaternion`, the numpy reference): the
    filters apply an error to one attitude or to their 13 sigma points at every update,
    about 25 us a call in numpy."""
    return first_call(
        _perturbed_quaternions,
        "the filters' error reset",
        np.ascontiguousarray(delta, dtype=float),
        np.ascontiguousarray(reference, dtype=float),
    )


@_jit
def _perturbed_quaternions(delta: Array, reference: Array) -> Array:
    """:func:`perturbed_quaternions`' loop."""
    out = np.empty((delta.shape[0], 4))
    shared = reference.shape[0] == 1
    for i in range(delta.shape[0]):
        perturbed_into(delta[i], reference[0 if shared else i], out[i])
    return out


def block_nis(
    innovation: Array,
    factor: Array,
    weight: Array,
    noise: Array,
    members: NDArray[np.intp],
) -> tuple[Array, NDArray[np.intp]]:
    """Each row's block's ``nu_b^T S_b^-1 nu_b`` and the block's size, ``S = F^T W F + R``
    (:func:`attopt.solvers.filters.common.block_nis`; its numpy reference
    :func:`~attopt.solvers.filters.common.block_nis_reference` takes the same arguments
    but the block labels for ``members``, the rows of each row's block,
    :attr:`attopt.solvers.blocks.BlockMembers.members`).

    One loop over the blocks: each forms its ``S_b`` and solves it by Gaussian
    elimination with partial pivoting (LAPACK's ``gesv``, numpy's, pivots the same way).
    In numpy the same work is a dozen calls per block size, about 60 us an epoch,
    which the filters and smoothers pay at every update.  NaN where ``S_b`` or the
    innovation is not finite, or ``S_b`` is singular (numpy's ``solve`` raises there).
    """
    full = noise.ndim == 2
    return first_call(
        _block_nis,
        "the gate's normalised innovations",
        np.ascontiguousarray(innovation, dtype=float),
        np.ascontiguousarray(factor, dtype=float),
        np.ascontiguousarray(weight, dtype=float),
        np.ascontiguousarray(noise if full else noise[None], dtype=float),
        full,
        np.ascontiguousarray(members),
    )


@_jit
def _block_nis(
    innovation: Array,
    factor: Array,
    weight: Array,
    noise: Array,
    full: bool,
    members: NDArray[np.intp],
) -> tuple[Array, NDArray[np.intp]]:
    """:func:`block_nis`' loop (``noise`` ``(1, m)`` variances unless ``full``)."""
    m, width = members.shape
    k = factor.shape[0]
    nis = np.full(m, np.nan)
    sizes = np.zeros(m, dtype=np.intp)
    weighted = np.empty((k, width))
    s = np.empty((width, width))
    x = np.empty(width)
    for leader in range(m):
        if members[leader, 0] != leader:  # not its block's first row
            continue
        size = 0
        while size < width and members[leader, size] >= 0:
            size += 1
        rows = members[leader, :size]
        for a in range(k):  # W F_b
            for q in range(size):
                total = 0.0
                for b in range(k):
                    total += weight[a, b] * factor[b, rows[q]]
                weighted[a, q] = total
        for p in range(size):  # F_b^T (W F_b) + R_b
            for q in range(size):
                total = 0.0
                for a in range(k):
                    total += factor[a, rows[p]] * weighted[a, q]
                if full:
                    total += noise[rows[p], rows[q]]
                elif p == q:
                    total += noise[0, rows[p]]
                s[p, q] = total
            x[p] = innovation[rows[p]]
        value = _solved_square(s, x, size)
        for p in range(size):
            nis[rows[p]] = value
            sizes[rows[p]] = size
    return nis, sizes


@_jit
def _solved_square(s: Array, x: Array, size: int) -> float:
    """``x^T S^-1 x`` over the leading ``size`` rows and columns (both overwritten), by
    Gaussian elimination with partial pivoting; NaN if not finite or singular."""
    nu = x[:size].copy()
    for p in range(size):
        if not math.isfinite(x[p]):
            return math.nan
        for q in range(size):
            if not math.isfinite(s[p, q]):
                return math.nan
    for c in range(size):
        pivot = c
        for r in range(c + 1, size):
            if abs(s[r, c]) > abs(s[pivot, c]):
                pivot = r
        if s[pivot, c] == 0.0:
            return math.nan
        if pivot != c:
            for q in range(size):
                s[c, q], s[pivot, q] = s[pivot, q], s[c, q]
            x[c], x[pivot] = x[pivot], x[c]
        for r in range(c + 1, size):
            ratio = s[r, c] / s[c, c]
            for q in range(c, size):
                s[r, q] -= ratio * s[c, q]
            x[r] -= ratio * x[c]
    value = 0.0
    for c in range(size - 1, -1, -1):
        total = x[c]
        for q in range(c + 1, size):
            total -= s[c, q] * x[q]
        x[c] = total / s[c, c]
    for c in range(size):
        value += nu[c] * x[c]
    return value


def information_gain(
    information: Array, h: Array, variances: Array, innovation: Array
) -> tuple[Array, float, Array]:
    """Gain ``K = P+ H^T R^-1``, ``nu^T S^-1 nu`` and ``P+ = (P^-1 + H^T R^-1 H)^-1`` from
    the prior information ``P^-1``, ``H`` ``(m, n)`` and ``R``'s ``variances`` ``(m,)``
    (:func:`attopt.solvers.filters.common.kalman_gain`; its numpy reference
    :func:`~attopt.solvers.filters.common.gain_reference`)."""
    return first_call(
        _information_gain,
        "the filters' information-form gain",
        np.ascontiguousarray(information, dtype=float),
        np.ascontiguousarray(h, dtype=float),
        np.ascontiguousarray(variances, dtype=float),
        np.ascontiguousarray(innovation, dtype=float),
    )


@_jit
def _information_gain(
    information: Array, h: Array, variances: Array, innovation: Array
) -> tuple[Array, float, Array]:
    """:func:`information_gain`' loop."""
    m, n = h.shape
    weighted = np.empty((m, n))  # R^-1 H
    total = information.copy()  # P^-1 + H^T R^-1 H
    projected = np.zeros(n)  # H^T R^-1 nu
    nis = 0.0
    for i in range(m):
        scaled = innovation[i] / variances[i]
        nis += innovation[i] * scaled
        for a in range(n):
            weighted[i, a] = h[i, a] / variances[i]
            projected[a] += h[i, a] * scaled
        for a in range(n):
            for b in range(n):
                total[a, b] += h[i, a] * weighted[i, b]
    posterior = np.linalg.inv(total)
    gain = posterior @ weighted.T
    nis -= projected @ posterior @ projected
    return gain, nis, posterior


def smallest_attitude_variance(covariance: Array) -> float:
    """The smallest eigenvalue of the attitude block ``covariance[:3, :3]``
    (:func:`attopt.solvers.filters.common.linearised`); NaN if the block is not finite
    (numpy's ``eigvalsh`` gives NaN for an infinite entry and raises for a NaN one)."""
    return first_call(
        _smallest_attitude_variance,
        "the attitude block's smallest variance",
        np.ascontiguousarray(covariance[:3, :3], dtype=float),
    )


@_jit
def _smallest_attitude_variance(block: Array) -> float:
    """:func:`smallest_attitude_variance`' call (LAPACK's symmetric eigenvalues)."""
    if not np.isfinite(block).all():
        return np.nan
    return np.linalg.eigvalsh(block)[0]


def symmetric_positive(p: Array) -> tuple[Array, bool]:
    """``(p + p^T) / 2`` and whether it has a Cholesky factor
    (:func:`attopt.solvers.filters.common.repair_covariance`, which floors the eigenvalues
    of one that has not)."""
    return first_call(
        _symmetric_positive, "the covariance's definiteness test", np.ascontiguousarray(p)
    )


@_jit
def _symmetric_positive(p: Array) -> tuple[Array, bool]:
    """:func:`symmetric_positive`' loop: a Cholesky factorisation that stops at the first
    pivot that is not positive."""
    n = p.shape[0]
    symmetric = 0.5 * (p + p.T)
    factor = np.zeros((n, n))
    for j in range(n):
        pivot = symmetric[j, j]
        for k in range(j):
            pivot -= factor[j, k] * factor[j, k]
        if pivot <= 0.0:  # a NaN goes on, as numpy's factorisation does not raise for it
            return symmetric, False
        factor[j, j] = math.sqrt(pivot)
        for i in range(j + 1, n):
            total = symmetric[i, j]
            for k in range(j):
                total -= factor[i, k] * factor[j, k]
            factor[i, j] = total / factor[j, j]
    return symmetric, True


# Warm-ups (attopt.formulations.kernels.WARM_UPS): a two-row update of a 6-state filter.
register_warm_up(
    "filters.error_reset",
    lambda: perturbed_quaternions(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.0, 1.0]])),
)
register_warm_up(
    "filters.gate",
    lambda: block_nis(
        np.zeros(2), np.zeros((6, 2)), np.eye(6), np.ones(2), np.array([[0, 1], [0, 1]], np.intp)
    ),
)
register_warm_up(
    "filters.gain",
    lambda: information_gain(np.eye(6), np.ones((2, 6)), np.ones(2), np.zeros(2)),
)
register_warm_up("filters.smallest_variance", lambda: smallest_attitude_variance(np.eye(6)))
register_warm_up("filters.definiteness", lambda: symmetric_positive(np.eye(6)))
