"""Wahba's solvers compiled with numba, one epoch at a time: the default path of every call.

The numpy methods (:mod:`~attopt.solvers.wahba.qmethod`, :mod:`~attopt.solvers.wahba.quest`,
...) are vectorised over epochs; they remain the reference
(:meth:`attopt.solvers.wahba.WahbaSolver.numpy_reference`, or ``ATTOPT_KERNELS=interpreted``
for every call, :data:`attopt.formulations.kernels.KERNELS_ENV`).  Their cost is numpy's
per-call overhead: 0.3-0.7 ms of small-array calls for one epoch, and a few dozen passes
over the batch's arrays (0.4-0.8 M epochs/s).  Here every epoch is validated
(:data:`~attopt.formulations.vector_observations.CHECKS`, in the same order and with the
same reasons), reduced to its profile matrix ``B`` (Cilden Guler et al. 2017 eq. 15),
solved, and scored in one loop of machine code.  Written by hand, with numba, because no
library solves Wahba's problem per epoch in compiled code (scipy's ``align_vectors``
takes 50-70 us a call).  The two paths agree to ``200 eps lambda_0 / gap`` (QUEST: to
``(lambda_0 / gap)^2``, its own accuracy), ``gap`` the eigen-gap of Davenport's ``K``
(``tests/test_wahba_compiled.py``).

Per method (the equation numbers of Cilden Guler et al. 2017):

* TRIAD: the frames of eqs. 5-9, ``A = M_B M_R^T`` (eq. 10), covariance eq. 11;
* SVD: eqs. 17-18 with the SVD by one-sided Jacobi rotations (Hestenes 1958), covariance
  eq. 19;
* q-method: the top eigenpair of Davenport's ``K`` (eqs. 23-26) by Jacobi rotations
  (Golub and Van Loan 2013, sec. 8.5), covariance eq. 19;
* QUEST: Newton on the characteristic quartic, the sequential rotations and one
  Rayleigh refinement, eqs. 27-31 (:mod:`~attopt.solvers.wahba.quest`), covariance eq. 32;
* FOAM: Newton on Markley's quartic, eqs. 33-35, covariance eq. 37.

The helpers are inlined into each method's loop (numba counts the references of every
array passed to a function that is not, which cost more than a QUEST solve), one loop
per method.  numba caches the machine code on disk beside this module (``__pycache__``,
or ``$NUMBA_CACHE_DIR``): the first call of a method on a machine compiles its loop
(8-15 s, printed on standard error by
:func:`~attopt.formulations.kernels.report_compilation`), later processes load it
(0.01-0.2 s).

Example::

    >>> import numpy as np
    >>> body = reference = np.eye(3)[None, :2]
    >>> out = solve_epochs(QUEST, body, reference, np.ones((1, 2)), np.ones((1, 2), bool), 1e-3)
    >>> solved = Solved.of(out)
    >>> solved.code.tolist(), np.allclose(solved.quaternion, [0.0, 0.0, 0.0, 1.0], atol=1e-12)
    ([0], True)
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations.kernels import first_call, register_warm_up
from attopt.formulations.vector_observations import (
    BAD_WEIGHT,
    BODY_PARALLEL,
    MIN_NORM,
    NONFINITE,
    REFERENCE_PARALLEL,
    TOO_FEW,
    ZERO_LENGTH,
)
from attopt.solvers.newton import MAX_ITERATIONS, RTOL

Array = NDArray[np.float64]

_jit = njit(cache=True, error_model="numpy", inline="always")
"""numba's compilation, cached on disk, with numpy's float semantics (a division by zero
gives inf or NaN, as in the numpy methods, instead of raising; no checks in the loops)."""

TRIAD, SVD, Q_METHOD, QUEST, FOAM = range(5)
"""Method codes of :func:`solve_epochs`."""
DIAGNOSTICS: dict[int, tuple[str, ...]] = {
    TRIAD: ("anchor", "partner"),
    SVD: ("s3",),
    Q_METHOD: ("lambda_max", "eigen_gap"),
    QUEST: ("iterations", "lambda_max", "sequential_rotation"),
    FOAM: ("iterations", "lambda_max"),
}
"""Names of each method's diagnostics, the columns of :attr:`Solved.diagnostics`."""
NAMES = ("triad", "svd", "q_method", "quest", "foam")
"""The registry names of the compiled methods, by code."""
ORTHOGONALITY = 1e-12
"""Largest entry of ``A A^T - I`` taken as a rotation matrix (scipy's ``from_matrix``)."""
JACOBI_SWEEPS = 20
"""Most Jacobi sweeps of the q-method (three to five reach round-off on Wahba's ``K``)."""
EPS = np.finfo(float).eps
EPS2 = EPS**2
"""Jacobi stops when the off-diagonal's squared norm is below ``EPS2`` times ``K``'s."""


COLUMNS = 19
"""Per epoch, the columns of :func:`solve_epochs`' result: the check code (0 when valid),
whether the method converged (1.0), the canonical scipy quaternion (4), the covariance
(9, rad^2), Wahba's loss (eq. 14) and up to three diagnostics (:data:`DIAGNOSTICS`); NaN
where the epoch is invalid or not converged.  One buffer, because every array a compiled
call takes or returns costs about 0.2 us of conversion."""
CODE, CONVERGED, QUATERNION, COVARIANCE, LOSS, DIAGNOSTIC = 0, 1, 2, 6, 15, 16


class Solved(NamedTuple):
    """The columns of :func:`solve_epochs`' result as arrays (:data:`COLUMNS`)."""

    code: NDArray[np.intp]
    converged: NDArray[np.bool_]
    quaternion: Array
    covariance: Array
    loss: Array
    diagnostics: Array

    @classmethod
    def of(cls, out: Array) -> Solved:
        """The arrays of the buffer ``out`` ``(N, COLUMNS)``."""
        return cls(
            out[:, CODE].astype(np.intp),
            out[:, CONVERGED] != 0.0,
            np.ascontiguousarray(out[:, QUATERNION:COVARIANCE]),
            out[:, COVARIANCE:LOSS].reshape(-1, 3, 3),
            out[:, LOSS].copy(),
            out[:, DIAGNOSTIC:],
        )


def solve_epochs(
    method: int,
    body: Array,
    reference: Array,
    weights: Array,
    present: NDArray[np.bool_],
    tolerance: float,
) -> Array:
    """Solve ``N`` epochs of ``(N, n, 3)`` vectors (``(N, n)`` weights and present mask, as
    :func:`~attopt.formulations.vector_observations.as_batch` returns them) by ``method``:
    the ``(N, COLUMNS)`` buffer of :data:`COLUMNS` (:meth:`Solved.of` splits it)."""
    out = np.empty((weights.shape[0], COLUMNS))
    # C-contiguous inputs: numba compiles (and caches) one loop per array layout.
    first_call(
        _SOLVE[method],
        f"the {NAMES[method]} Wahba loop",
        np.ascontiguousarray(body),
        np.ascontiguousarray(reference),
        np.ascontiguousarray(weights),
        np.ascontiguousarray(present),
        tolerance,
        out,
    )
    return out


@_jit
def _drive(method, body, reference, weights, present, tolerance, out):
    """Every epoch: validate, form ``B``, solve by ``method``, score; into ``out``."""
    n_obs = weights.shape[1]
    bu = np.empty((n_obs, 3))
    ru = np.empty((n_obs, 3))
    aw = np.empty(n_obs)
    b = np.empty((3, 3))
    a = np.empty((3, 3))
    k = np.empty((4, 4))  # workspaces of the methods
    v = np.empty((4, 4))
    for e in range(weights.shape[0]):
        row = out[e]
        q = row[QUATERNION:COVARIANCE]
        p = row[COVARIANCE:LOSS].reshape((3, 3))
        d = row[DIAGNOSTIC:]
        code = _validate(body[e], reference[e], weights[e], present[e], tolerance, bu, ru, aw)
        row[CODE] = code
        d[:] = np.nan
        ok = code == 0
        if ok:
            _profile(bu, ru, aw, b)
            ok = method(bu, ru, aw, b, k, v, q, p, d)
        row[CONVERGED] = 1.0 if ok or code != 0 else 0.0
        if ok:
            _canonical(q)
            _matrix(q, a)
            # Wahba's loss as lambda_0 - tr(A B^T) (eq. 16), rounding below 0 clipped.
            trace = 0.0
            for i in range(3):
                for j in range(3):
                    trace += a[i, j] * b[i, j]
            row[LOSS] = max(np.sum(aw) - trace, 0.0)
        else:
            row[QUATERNION:] = np.nan


@_jit
def _validate(b, r, a, present, tolerance, bu, ru, aw):
    """The check code of one epoch (``CHECKS``); unit vectors and weights into ``bu``,
    ``ru``, ``aw`` (zero where absent)."""
    nonfinite = short = bad_weight = False
    count = 0
    for i in range(a.shape[0]):
        b0, b1, b2 = b[i, 0], b[i, 1], b[i, 2]
        r0, r1, r2 = r[i, 0], r[i, 1], r[i, 2]
        nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        nr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        usable = present[i]
        if usable:
            count += 1
            bad_weight |= not (a[i] > 0.0 and math.isfinite(a[i]))
            if not (math.isfinite(nb) and math.isfinite(nr)):
                nonfinite = True
                usable = False
            elif nb < MIN_NORM or nr < MIN_NORM:
                usable = False
                short = True
        if usable:
            bu[i, 0], bu[i, 1], bu[i, 2] = b0 / nb, b1 / nb, b2 / nb
            ru[i, 0], ru[i, 1], ru[i, 2] = r0 / nr, r1 / nr, r2 / nr
            aw[i] = a[i]
        else:
            bu[i, 0] = bu[i, 1] = bu[i, 2] = ru[i, 0] = ru[i, 1] = ru[i, 2] = aw[i] = 0.0
    if nonfinite:
        return NONFINITE
    if short:
        return ZERO_LENGTH
    if bad_weight:
        return BAD_WEIGHT
    if count < 2:
        return TOO_FEW
    if _largest_cross(bu, present) < tolerance:
        return BODY_PARALLEL
    if _largest_cross(ru, present) < tolerance:
        return REFERENCE_PARALLEL
    return 0


@_jit
def _largest_cross(u, present):
    """The largest ``|u_i x u_j| = sqrt(1 - (u_i . u_j)^2)`` over present pairs."""
    largest = 0.0
    for i in range(u.shape[0]):
        for j in range(i + 1, u.shape[0]):
            if present[i] and present[j]:
                dot = u[i, 0] * u[j, 0] + u[i, 1] * u[j, 1] + u[i, 2] * u[j, 2]
                largest = max(largest, 1.0 - dot * dot)
    return math.sqrt(largest)


@_jit
def _profile(bu, ru, aw, b):
    """``B = sum_i a_i b_i r_i^T`` (eq. 15)."""
    b[:, :] = 0.0
    for i in range(aw.shape[0]):
        for j in range(3):
            weighted = aw[i] * bu[i, j]
            for k in range(3):
                b[j, k] += weighted * ru[i, k]


@_jit
def _dot(u, v):
    """``u . v`` without the temporary array of ``np.sum(u * v)``."""
    total = 0.0
    for i in range(u.shape[0]):
        total += u[i] * v[i]
    return total


@_jit
def _det3(m):
    return (
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )


@_jit
def _principal_minor(m, i):
    """The ``3 x 3`` principal minor of the ``4 x 4`` ``m`` without row and column ``i``."""
    r0, r1, r2 = (i + 1) % 4, (i + 2) % 4, (i + 3) % 4
    return (
        m[r0, r0] * (m[r1, r1] * m[r2, r2] - m[r1, r2] * m[r2, r1])
        - m[r0, r1] * (m[r1, r0] * m[r2, r2] - m[r1, r2] * m[r2, r0])
        + m[r0, r2] * (m[r1, r0] * m[r2, r1] - m[r1, r1] * m[r2, r0])
    )


@_jit
def _product(a, b):
    """``a b`` by loops: numba's ``@`` calls BLAS, whose overhead dwarfs a ``3 x 3`` product."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            for j in range(b.shape[1]):
                out[i, j] += a[i, k] * b[k, j]
    return out


@_jit
def _cross(u, v, out):
    out[0] = u[1] * v[2] - u[2] * v[1]
    out[1] = u[2] * v[0] - u[0] * v[2]
    out[2] = u[0] * v[1] - u[1] * v[0]


@_jit
def _davenport(b, k):
    """Davenport's ``K`` (eqs. 23-25) into ``k``."""
    trace = b[0, 0] + b[1, 1] + b[2, 2]
    for i in range(3):
        for j in range(3):
            k[i, j] = b[i, j] + b[j, i]
        k[i, i] -= trace
    k[0, 3] = k[3, 0] = b[1, 2] - b[2, 1]
    k[1, 3] = k[3, 1] = b[2, 0] - b[0, 2]
    k[2, 3] = k[3, 2] = b[0, 1] - b[1, 0]
    k[3, 3] = trace


@_jit
def _largest_root(c2, c3, c4, start):
    """Newton on ``x^4 + c2 x^2 + c3 x + c4`` from ``start`` (:mod:`attopt.solvers.newton`,
    the same steps and stopping rule): the root, the iterations and whether it converged."""
    x = start
    scale = abs(start)
    for iteration in range(1, MAX_ITERATIONS + 1):
        f = (((1.0 * x + 0.0) * x + c2) * x + c3) * x + c4
        df = ((4.0 * x + 0.0) * x + 2.0 * c2) * x + c3
        step = f / df if df != 0.0 else 0.0
        x -= step
        if not abs(step) > RTOL * scale or step < 0.0:
            return x, iteration, True
    return x, MAX_ITERATIONS, False


@_jit
def _inverse_symmetric(a, b, c, d, e, f, out):
    """Inverse of ``[[a, b, c], [b, d, e], [c, e, f]]`` by cofactors."""
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    inv_det = 1.0 / (a * c00 + b * c01 + c * c02)
    out[0, 0] = c00 * inv_det
    out[0, 1] = out[1, 0] = c01 * inv_det
    out[0, 2] = out[2, 0] = c02 * inv_det
    out[1, 1] = c11 * inv_det
    out[1, 2] = out[2, 1] = c12 * inv_det
    out[2, 2] = c22 * inv_det


@_jit
def _svd_covariance(b, a, out):
    """``[tr(B A^T) I - B A^T]^-1``, eq. 19 at the optimum
    (:func:`attopt.formulations.wahba_covariance.svd_covariance`)."""
    m = _product(b, a.T)
    _inverse_symmetric(
        m[1, 1] + m[2, 2],
        -0.5 * (m[0, 1] + m[1, 0]),
        -0.5 * (m[0, 2] + m[2, 0]),
        m[0, 0] + m[2, 2],
        -0.5 * (m[1, 2] + m[2, 1]),
        m[0, 0] + m[1, 1],
        out,
    )


@_jit
def _matrix(q, a):
    """The attitude matrix of the scipy quaternion ``q`` (``Rotation.as_matrix``)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    a[0, 0] = x2 - y2 - z2 + w2
    a[1, 0] = 2.0 * (xy + zw)
    a[2, 0] = 2.0 * (xz - yw)
    a[0, 1] = 2.0 * (xy - zw)
    a[1, 1] = -x2 + y2 - z2 + w2
    a[2, 1] = 2.0 * (yz + xw)
    a[0, 2] = 2.0 * (xz + yw)
    a[1, 2] = 2.0 * (yz - xw)
    a[2, 2] = -x2 - y2 + z2 + w2


@_jit
def _quaternion(a, q):
    """The scipy quaternion of the rotation matrix ``a`` as ``Rotation.from_matrix`` gives it:
    a matrix whose Gram matrix is not the identity to 1e-12 is first replaced by its nearest
    rotation ``U V^T``; then the largest of the diagonal and the trace picks the stable
    formula."""
    if np.any(np.abs(_product(a, a.T) - np.eye(3)) > ORTHOGONALITY):
        u, _, vt = np.linalg.svd(a)
        a = _product(u, vt)
    trace = a[0, 0] + a[1, 1] + a[2, 2]
    choice = 3
    largest = trace
    for i in range(3):
        if a[i, i] > largest:
            largest = a[i, i]
            choice = i
    if choice == 3:
        q[0] = a[2, 1] - a[1, 2]
        q[1] = a[0, 2] - a[2, 0]
        q[2] = a[1, 0] - a[0, 1]
        q[3] = 1.0 + trace
    else:
        i = choice
        j = (i + 1) % 3
        k = (j + 1) % 3
        q[i] = 1.0 - trace + 2.0 * a[i, i]
        q[j] = a[j, i] + a[i, j]
        q[k] = a[k, i] + a[i, k]
        q[3] = a[k, j] - a[j, k]
    q /= math.sqrt(_dot(q, q))


@_jit
def _canonical(q):
    """``q`` normalised with ``w >= 0`` (scipy's canonical form: if ``w`` is 0, the first
    nonzero component positive)."""
    q /= math.sqrt(_dot(q, q))
    for i in (3, 0, 1, 2):
        if q[i] != 0.0:
            if q[i] < 0.0:
                q *= -1.0
            return


@_jit
def _triad_frame(u, v):
    """``M = [u : r : u x r]`` with ``r = u x v / |u x v|`` (eqs. 5-9)."""
    m = np.empty((3, 3))
    r = np.empty(3)
    s = np.empty(3)
    _cross(u, v, r)
    r /= math.sqrt(_dot(r, r))
    _cross(u, r, s)
    m[:, 0] = u
    m[:, 1] = r
    m[:, 2] = s
    return m


@_jit
def _triad(bu, ru, aw, b, k, v, q, p, d):
    """TRIAD on the heaviest observation and its best partner (:mod:`~.triad`), eqs. 5-11."""
    anchor = np.argmax(aw)
    u = bu[anchor]
    partner = 0
    best = -np.inf
    c = np.empty(3)
    for j in range(aw.shape[0]):
        _cross(u, bu[j], c)
        score = -1.0 if j == anchor else aw[j] * _dot(c, c)
        if score > best:
            best = score
            partner = j
    v = bu[partner]
    _quaternion(_product(_triad_frame(u, v), _triad_frame(ru[anchor], ru[partner]).T), q)
    # Eq. 11: s1^2 I + [(s2^2 - s1^2) u u^T + s1^2 (u.v)(u v^T + v u^T)] / |u x v|^2.
    s1, s2 = 1.0 / aw[anchor], 1.0 / aw[partner]
    _cross(u, v, c)
    cross2 = _dot(c, c)
    dot = _dot(u, v)
    for i in range(3):
        for j in range(3):
            p[i, j] = ((s2 - s1) * u[i] * u[j] + s1 * dot * (u[i] * v[j] + v[i] * u[j])) / cross2
        p[i, i] += s1
    d[0] = anchor
    d[1] = partner
    return True


@_jit
def _svd(bu, ru, aw, b, k, v, q, p, d):
    """``A = U diag[1, 1, det U det V] V^T`` for ``B = U Sigma V^T`` (eqs. 17-18),
    covariance eq. 19.

    The SVD by one-sided Jacobi rotations (Hestenes 1958; Demmel and Veselic 1992, as
    LAPACK's ``dgesvj``): the columns of ``W = B V`` are made orthogonal, then
    ``sigma_k = |w_k|`` and ``u_k = w_k / sigma_k``.  Only the smallest ``sigma_k`` is told
    apart (it takes the sign ``d``), so with the other two, ``i`` and ``j`` in cyclic order,
    ``A = u_i v_i^T + u_j v_j^T + det(V) (u_i x u_j) v_k^T`` and ``d sigma_k =
    det(V) (u_i x u_j) . w_k``: no division by a vanishing ``sigma_k`` (two vectors give a
    rank-2 ``B``).
    """
    w = b.copy()
    v = np.eye(3)
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for i in range(2):
            for j in range(i + 1, 3):
                alpha = w[0, i] * w[0, i] + w[1, i] * w[1, i] + w[2, i] * w[2, i]
                beta = w[0, j] * w[0, j] + w[1, j] * w[1, j] + w[2, j] * w[2, j]
                gamma = w[0, i] * w[0, j] + w[1, i] * w[1, j] + w[2, i] * w[2, j]
                if abs(gamma) <= EPS * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = c * t
                for m in range(3):
                    wi, wj = w[m, i], w[m, j]
                    w[m, i] = c * wi - s * wj
                    w[m, j] = s * wi + c * wj
                    vi, vj = v[m, i], v[m, j]
                    v[m, i] = c * vi - s * vj
                    v[m, j] = s * vi + c * vj
        if not rotated:
            break
    sigma = np.empty(3)
    for m in range(3):
        sigma[m] = math.sqrt(w[0, m] * w[0, m] + w[1, m] * w[1, m] + w[2, m] * w[2, m])
    k = np.argmin(sigma)
    i, j = (k + 1) % 3, (k + 2) % 3
    ui = w[:, i] / sigma[i]
    uj = w[:, j] / sigma[j]
    uk = np.empty(3)
    _cross(ui, uj, uk)
    sign = _det3(v)
    a = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            a[r, c] = ui[r] * v[c, i] + uj[r] * v[c, j] + sign * uk[r] * v[c, k]
    _quaternion(a, q)
    _svd_covariance(b, a, p)
    d[0] = sign * _dot(uk, w[:, k])
    return True


@_jit
def _rotation(k, i, j):
    """``t = tan``, ``s = sin`` and ``tau = tan(angle / 2)`` of the Jacobi rotation that
    zeroes ``k[i, j]`` (Press et al. 2007, sec. 11.1)."""
    kij = k[i, j]
    if kij == 0.0:
        return 0.0, 0.0, 0.0
    theta = (k[j, j] - k[i, i]) / (2.0 * kij)
    t = math.copysign(1.0, theta) / (abs(theta) + math.sqrt(theta * theta + 1.0))
    c = 1.0 / math.sqrt(t * t + 1.0)
    s = t * c
    return t, s, s / (1.0 + c)


@_jit
def _rotate(k, v, i, j, t, s, tau):
    """Apply the rotation of :func:`_rotation` in the plane ``(i, j)`` to ``k`` and ``v``."""
    kij = k[i, j]
    k[i, i] -= t * kij
    k[j, j] += t * kij
    k[i, j] = k[j, i] = 0.0
    for m in range(4):
        if m != i and m != j:
            g, h = k[m, i], k[m, j]
            k[m, i] = k[i, m] = g - s * (h + g * tau)
            k[m, j] = k[j, m] = h + s * (g - h * tau)
        g, h = v[m, i], v[m, j]
        v[m, i] = g - s * (h + g * tau)
        v[m, j] = h + s * (g - h * tau)


@_jit
def _jacobi(k, v):
    """Diagonalise the symmetric ``4 x 4`` ``k`` in place by Jacobi rotations, accumulating
    them in ``v`` (eigenvectors in its columns): Golub and Van Loan 2013, sec. 8.5, in the
    parallel ordering (each step rotates two disjoint planes, ``(0, 1)`` and ``(2, 3)``,
    then ``(0, 2)`` and ``(1, 3)``, then ``(0, 3)`` and ``(1, 2)``, whose rotations can be
    computed together)."""
    v[:, :] = 0.0
    scale = 0.0
    for i in range(4):
        v[i, i] = 1.0
        for j in range(4):
            scale += k[i, j] * k[i, j]
    for _ in range(JACOBI_SWEEPS):
        off = 0.0
        for i in range(4):
            for j in range(i + 1, 4):
                off += k[i, j] * k[i, j]
        if off <= EPS2 * scale:
            return
        for partner in range(1, 4):
            # Planes (0, partner) and the other two indices (a, b).
            a = 1 if partner != 1 else 2
            b = 6 - partner - a
            t1, s1, tau1 = _rotation(k, 0, partner)
            t2, s2, tau2 = _rotation(k, a, b)
            if s1 != 0.0:
                _rotate(k, v, 0, partner, t1, s1, tau1)
            if s2 != 0.0:
                _rotate(k, v, a, b, t2, s2, tau2)


@_jit
def _q_method(bu, ru, aw, b, k, v, q, p, d):
    """The eigenvector of ``K``'s largest eigenvalue (eq. 26), covariance eq. 19."""
    _davenport(b, k)
    _jacobi(k, v)
    top = 0
    for i in range(1, 4):
        if k[i, i] > k[top, top]:
            top = i
    second = -np.inf
    for i in range(4):
        if i != top:
            second = max(second, k[i, i])
    q[0], q[1], q[2], q[3] = -v[0, top], -v[1, top], -v[2, top], v[3, top]  # Shuster -> scipy
    q /= math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    a = np.empty((3, 3))
    _matrix(q, a)
    _svd_covariance(b, a, p)
    d[0] = k[top, top]
    d[1] = k[top, top] - second
    return True


@_jit
def _turned_invariants(b, axis):
    """``S = B' + B'^T``, ``z`` (eq. 25), ``S z`` and ``tr B'`` of ``B' = B diag(signs)``,
    the reference frame turned by 180 deg about ``axis`` (``-1``: not turned)."""
    c0 = 1.0 if axis < 0 or axis == 0 else -1.0
    c1 = 1.0 if axis < 0 or axis == 1 else -1.0
    c2 = 1.0 if axis < 0 or axis == 2 else -1.0
    t00, t01, t02 = b[0, 0] * c0, b[0, 1] * c1, b[0, 2] * c2
    t10, t11, t12 = b[1, 0] * c0, b[1, 1] * c1, b[1, 2] * c2
    t20, t21, t22 = b[2, 0] * c0, b[2, 1] * c1, b[2, 2] * c2
    s00, s11, s22 = 2.0 * t00, 2.0 * t11, 2.0 * t22
    s01, s02, s12 = t01 + t10, t02 + t20, t12 + t21
    z0, z1, z2 = t12 - t21, t20 - t02, t01 - t10
    sz0 = s00 * z0 + s01 * z1 + s02 * z2
    sz1 = s01 * z0 + s11 * z1 + s12 * z2
    sz2 = s02 * z0 + s12 * z1 + s22 * z2
    return (s00, s11, s22, s01, s02, s12), (z0, z1, z2), (sz0, sz1, sz2), t00 + t11 + t22


@_jit
def _symmetric_det(s):
    """Determinant of ``[[s0, s3, s4], [s3, s1, s5], [s4, s5, s2]]``."""
    s00, s11, s22, s01, s02, s12 = s
    return (
        s00 * (s11 * s22 - s12 * s12)
        - s01 * (s01 * s22 - s12 * s02)
        + s02 * (s01 * s12 - s11 * s02)
    )


@_jit
def _trace_adjugate(s, sigma):
    """``tr adj S = ((tr S)^2 - tr(S^2)) / 2`` with ``tr S = 2 sigma``."""
    s00, s11, s22, s01, s02, s12 = s
    squares = s00 * s00 + s11 * s11 + s22 * s22 + 2.0 * (s01 * s01 + s02 * s02 + s12 * s12)
    return 0.5 * ((2.0 * sigma) ** 2 - squares)


@_jit
def _quest_quaternion(b, axis, lam):
    """Normalised Shuster quaternion ``[x; gamma]`` of eqs. 27-31 in the frame turned about
    ``axis`` (:func:`_turned_invariants`)."""
    s, z, sz, sigma = _turned_invariants(b, axis)
    s00, s11, s22, s01, s02, s12 = s
    alpha = lam * lam - sigma * sigma + _trace_adjugate(s, sigma)  # eq. 27
    beta = lam - sigma  # eq. 28
    gamma = alpha * (lam + sigma) - _symmetric_det(s)  # eq. 29
    x0 = alpha * z[0] + beta * sz[0] + s00 * sz[0] + s01 * sz[1] + s02 * sz[2]  # eq. 30
    x1 = alpha * z[1] + beta * sz[1] + s01 * sz[0] + s11 * sz[1] + s12 * sz[2]
    x2 = alpha * z[2] + beta * sz[2] + s02 * sz[0] + s12 * sz[1] + s22 * sz[2]
    norm = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2 + gamma * gamma)
    return x0 / norm, x1 / norm, x2 / norm, gamma / norm


@_jit
def _after_turn(q, turn):
    """The scipy quaternion of ``Rotation(q) * turn`` for the 180 deg turn about axis
    ``turn - 1`` (``turn`` 0: none): the Hamilton product with that axis's unit quaternion
    (:data:`attopt.solvers.wahba.quest.TURN_COMPOSE`)."""
    if turn == 1:  # q (x) e_i = (q_w e_i + q_v x e_i, -q_i)
        return q[3], q[2], -q[1], -q[0]
    if turn == 2:
        return -q[2], q[3], q[0], -q[1]
    if turn == 3:
        return q[1], -q[0], q[3], -q[2]
    return q


@_jit
def _conjugate(q):
    """Shuster <-> scipy quaternion (``docs/conventions.md``)."""
    return -q[0], -q[1], -q[2], q[3]


@_jit
def _quest(bu, ru, aw, b, k, v, q, p, d):
    """QUEST with the sequential rotations and one Rayleigh refinement (:mod:`~.quest`)."""
    s, z, sz, sigma = _turned_invariants(b, -1)
    kappa = _trace_adjugate(s, sigma)
    a_ = sigma * sigma - kappa
    b_ = sigma * sigma + z[0] * z[0] + z[1] * z[1] + z[2] * z[2]
    c_ = _symmetric_det(s) + z[0] * sz[0] + z[1] * sz[1] + z[2] * sz[2]
    d_ = sz[0] * sz[0] + sz[1] * sz[1] + sz[2] * sz[2]
    lam, iterations, converged = _largest_root(
        -(a_ + b_), -c_, a_ * b_ + c_ * sigma - d_, np.sum(aw)
    )
    # The largest principal minor of lambda I - K (in v) picks the turn (quest.py).
    _davenport(b, k)
    for i in range(4):
        for j in range(4):
            v[i, j] = -k[i, j]
        v[i, i] += lam
    turn = 0
    largest = -1.0
    for i in range(4):
        minor = abs(_principal_minor(v, i))
        if minor > largest:
            largest = minor
            turn = (i + 1) % 4
    first = _conjugate(_after_turn(_conjugate(_quest_quaternion(b, turn - 1, lam)), turn))
    lam = 0.0
    for i in range(4):
        for j in range(4):
            lam += first[i] * k[i, j] * first[j]
    q[0], q[1], q[2], q[3] = _after_turn(_conjugate(_quest_quaternion(b, turn - 1, lam)), turn)
    # Eq. 32: P = [sum_i a_i (I - b_i b_i^T)]^-1.
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    for i in range(aw.shape[0]):
        x, y, w = bu[i, 0], bu[i, 1], bu[i, 2]
        m00 += aw[i] * x * x
        m01 += aw[i] * x * y
        m02 += aw[i] * x * w
        m11 += aw[i] * y * y
        m12 += aw[i] * y * w
        m22 += aw[i] * w * w
    total = np.sum(aw)
    _inverse_symmetric(total - m00, -m01, -m02, total - m11, -m12, total - m22, p)
    d[0] = iterations
    d[1] = lam
    d[2] = turn
    return converged


@_jit
def _adjugate(m):
    """Adjugate of a ``3 x 3`` matrix: rows ``c1 x c2``, ``c2 x c0``, ``c0 x c1`` of its
    columns ``c``."""
    out = np.empty((3, 3))
    c0 = m[:, 0].copy()
    c1 = m[:, 1].copy()
    c2 = m[:, 2].copy()
    _cross(c1, c2, out[0])
    _cross(c2, c0, out[1])
    _cross(c0, c1, out[2])
    return out


@_jit
def _foam(bu, ru, aw, b, k, v, q, p, d):
    """``A = [(kappa + |B|^2) B + lambda adj(B^T) - B B^T B] / zeta`` (eqs. 33-35),
    covariance ``(kappa I + B B^T) / zeta`` (eq. 37)."""
    fro2 = np.sum(b * b)
    adj = _adjugate(b)
    det = _det3(b)
    lam, iterations, converged = _largest_root(
        -2.0 * fro2, -8.0 * det, fro2 * fro2 - 4.0 * np.sum(adj * adj), np.sum(aw)
    )
    kappa = 0.5 * (lam * lam - fro2)
    zeta = kappa * lam - det
    bbt = _product(b, b.T)
    _quaternion(((kappa + fro2) * b + lam * _adjugate(b.T.copy()) - _product(bbt, b)) / zeta, q)
    p[:, :] = (kappa * np.eye(3) + bbt) / zeta
    d[0] = iterations
    d[1] = lam
    return converged


# One compiled loop per method (:func:`_drive` inlined with it), built on first use:
# written out, because numba caches module-level functions only, not closures a factory
# would make.
_options = {"cache": True, "error_model": "numpy"}


@njit(**_options)
def _solve_triad(body, reference, weights, present, tolerance, out):
    _drive(_triad, body, reference, weights, present, tolerance, out)


@njit(**_options)
def _solve_svd(body, reference, weights, present, tolerance, out):
    _drive(_svd, body, reference, weights, present, tolerance, out)


@njit(**_options)
def _solve_q_method(body, reference, weights, present, tolerance, out):
    _drive(_q_method, body, reference, weights, present, tolerance, out)


@njit(**_options)
def _solve_quest(body, reference, weights, present, tolerance, out):
    _drive(_quest, body, reference, weights, present, tolerance, out)


@njit(**_options)
def _solve_foam(body, reference, weights, present, tolerance, out):
    _drive(_foam, body, reference, weights, present, tolerance, out)


_SOLVE = (_solve_triad, _solve_svd, _solve_q_method, _solve_quest, _solve_foam)
"""The compiled loop of each method, by code."""


def _warm_up(method: int) -> Array:
    """One epoch of two vectors solved by ``method`` (its numba loop compiled or loaded)."""
    vectors = np.eye(3)[None, :2]
    return solve_epochs(method, vectors, vectors, np.ones((1, 2)), np.ones((1, 2), bool), 1e-3)


for _method, _name in enumerate(NAMES):
    register_warm_up(f"wahba.{_name}", partial(_warm_up, _method))
