"""The filters' gyro propagation compiled with numba: one call per prediction.

Between two epochs the MEKF and USQUE carry their state over every gyro step (ten steps
of 0.1 s between the 1 Hz vectors of ``wahba-mag-sun``): the covariance by ``P <- Phi_j
P Phi_j^T + Q_j`` with the transitions' product, and the attitude (USQUE: its 13 sigma
attitudes) by the increments ``exp(-[w_j x] dt_j)``.  In numpy each step is a few
small-array calls, and the whole prediction costs about 0.3 ms an epoch, most of it
numpy's per-call overhead; here a prediction is one loop of machine code: the MEKF's
two loops (:func:`covariance_steps`, :func:`quaternion_steps`), and USQUE's whole
unscented prediction with its sigma points' mean and covariance
(:func:`unscented_prediction`, which calls the same two loops inside).  Written by hand,
with numba, because no library propagates a Kalman filter's error state in compiled code
and CasADi's generated kernels take fixed sizes, while the number of steps between epochs
varies.

The formulas are those of the numpy functions, which remain the reference
(:func:`attopt.solvers.filters.common.propagate_covariance`,
:func:`~attopt.solvers.filters.common.propagate_quaternion` and
:func:`attopt.solvers.filters.usque.unscented_prediction` with ``ATTOPT_KERNELS=
interpreted``, :data:`attopt.formulations.kernels.KERNELS_ENV`): the transition is
:func:`attopt.formulations.gyro.error_state_transition` (Markley and Crassidis 2014, eqs.
6.83-6.84, with the same Taylor series below the same angle), the increment the
quaternion of :func:`attopt.formulations.quaternion_algebra.from_rotation_vector`
composed on the left.  The two paths agree to round-off (``tests/test_filters_compiled.py``:
1e-13 relative on covariances, 1e-14 on quaternions over a pass's steps).  numba caches
the machine code on disk beside this module (``__pycache__``, or ``$NUMBA_CACHE_DIR``):
the first use on a machine compiles each loop (a few seconds, printed on standard error
by :func:`~attopt.formulations.kernels.report_compilation`), later processes load it.

Example::

    >>> import numpy as np
    >>> rates, dt = np.zeros((10, 3)), np.full(10, 0.1)
    >>> covariance, total = covariance_steps(np.eye(6), rates, dt, np.zeros((10, 6, 6)))
    >>> bool(np.allclose(total[:3, 3:], np.eye(3)))  # Phi12 = I t for a zero rate
    True
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations.gyro import SERIES_LIMIT
from attopt.formulations.kernels import first_call, register_warm_up

Array = NDArray[np.float64]

_jit = njit(cache=True, error_model="numpy")
"""numba's compilation, cached on disk, with numpy's float semantics."""


@_jit
def _transition(rate: Array, dt: float, phi: Array) -> None:
    """Fill ``phi`` (6 x 6) with ``Phi = [[Phi11, Phi12], [0, I]]`` of one step
    (:func:`attopt.formulations.gyro.error_state_transition`)."""
    angle = math.sqrt(rate[0] ** 2 + rate[1] ** 2 + rate[2] ** 2) * dt
    cross = np.zeros((3, 3))
    cross[0, 1], cross[0, 2] = -rate[2] * dt, rate[1] * dt
    cross[1, 0], cross[1, 2] = rate[2] * dt, -rate[0] * dt
    cross[2, 0], cross[2, 1] = -rate[1] * dt, rate[0] * dt
    cross2 = cross @ cross
    if angle < SERIES_LIMIT:
        c1 = 0.5 - angle**2 / 24.0
        c2 = 1.0 / 6.0 - angle**2 / 120.0
        s1 = 1.0 - angle**2 / 6.0
    else:
        c1 = (1.0 - math.cos(angle)) / angle**2
        c2 = (angle - math.sin(angle)) / angle**3
        s1 = math.sin(angle) / angle
    phi[:] = 0.0
    for i in range(3):
        for j in range(3):
            eye = 1.0 if i == j else 0.0
            phi[i, j] = eye - s1 * cross[i, j] + c1 * cross2[i, j]
            phi[i, 3 + j] = (eye - c1 * cross[i, j] + c2 * cross2[i, j]) * dt
        phi[3 + i, 3 + i] = 1.0


def covariance_steps(
    covariance: Array, rates: Array, dt: Array, noise: Array
) -> tuple[Array, Array]:
    """``P <- Phi_j P Phi_j^T + Q_j`` over the steps ``j`` at ``rates`` ``(k, 3)`` with lengths
    ``dt`` ``(k,)`` and noises ``noise`` ``(k, 6, 6)``, and the product ``Phi_k ... Phi_1``
    (:func:`attopt.solvers.filters.common.propagate_covariance`); C-contiguous float
    arrays (numba compiles one loop per layout)."""
    return first_call(
        _covariance_steps, "the filters' covariance propagation loop", covariance, rates, dt, noise
    )


def quaternion_steps(quaternions: Array, rates: Array, dt: Array) -> Array:
    """Each of the ``(K, 4)`` scalar-last ``quaternions`` carried over the steps ``j`` at its
    own ``rates[i]`` ``(K, k, 3)`` with lengths ``dt`` ``(k,)``: ``q <- exp(-[w_j x] dt_j)
    q``, the increment's quaternion composed on the left
    (:func:`attopt.solvers.filters.common.propagate_quaternion`).  ``rates`` is copied
    if it is read-only (one attitude's rates broadcast to ``(1, k, 3)`` are): numba
    compiles one loop per array type, and a read-only array is another type."""
    rates = np.require(rates, float, ("C", "W"))
    return first_call(
        _quaternion_steps, "the filters' quaternion propagation loop", quaternions, rates, dt
    )


@_jit
def _covariance_steps(
    covariance: Array, rates: Array, dt: Array, noise: Array
) -> tuple[Array, Array]:
    """:func:`covariance_steps`' loop."""
    p = covariance.copy()
    total = np.eye(6)
    phi = np.empty((6, 6))
    for j in range(rates.shape[0]):
        _transition(rates[j], dt[j], phi)
        p = phi @ p @ phi.T + noise[j]
        total = phi @ total
    return p, total


@_jit
def _quaternion_steps(quaternions: Array, rates: Array, dt: Array) -> Array:
    """:func:`quaternion_steps`' loop."""
    out = quaternions.copy()
    for i in range(out.shape[0]):
        x, y, z, w = out[i, 0], out[i, 1], out[i, 2], out[i, 3]
        for j in range(rates.shape[1]):
            v0, v1, v2 = -rates[i, j, 0] * dt[j], -rates[i, j, 1] * dt[j], -rates[i, j, 2] * dt[j]
            # from_rotation_vector: [0.5 sinc(angle / 2 pi) v, cos(angle / 2)], numpy's sinc
            angle = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            half = math.pi * (angle / (2.0 * math.pi)) if angle != 0.0 else math.pi * 1e-20
            s = 0.5 * (math.sin(half) / half)
            a, b, c, d = s * v0, s * v1, s * v2, math.cos(0.5 * angle)
            # the Hamilton product [a, b, c, d] (x) [x, y, z, w] (left_matrices' rows)
            x, y, z, w = (
                d * x - c * y + b * z + a * w,
                c * x + d * y - a * z + b * w,
                -b * x + a * y + d * z + c * w,
                -a * x - b * y - c * z + d * w,
            )
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x, y, z, w
    return out


def unscented_prediction(
    offsets: Array, quaternion: Array, bias: Array, rates: Array, dt: Array, noise: Array
) -> tuple[Array, Array, Array, Array]:
    """USQUE's whole prediction (U1)-(U5) in one loop: the propagated attitude's quaternion,
    the mean error state, the covariance and the sigma points' deviations
    (:func:`attopt.solvers.filters.usque.unscented_prediction`, the numpy reference, which
    takes the same arguments)."""
    from attopt.solvers.filters.usque import COVARIANCE_WEIGHTS, WEIGHTS

    return first_call(
        _unscented_prediction,
        "USQUE's prediction loop",
        np.ascontiguousarray(offsets),
        np.ascontiguousarray(quaternion, dtype=float),
        np.ascontiguousarray(bias, dtype=float),
        np.ascontiguousarray(rates),
        np.ascontiguousarray(dt),
        np.ascontiguousarray(noise),
        WEIGHTS,
        COVARIANCE_WEIGHTS,
    )


@_jit
def perturbed_into(delta: Array, q: Array, out: Array) -> None:
    """``out`` = the quaternion of ``from_mrp(delta / 4)`` composed on the left of ``q``
    (:func:`attopt.solvers.filters.common.perturb_quaternion`)."""
    p0, p1, p2 = delta[0] / 4.0, delta[1] / 4.0, delta[2] / 4.0
    norm2 = p0 * p0 + p1 * p1 + p2 * p2
    a, b, c, d = (
        2.0 * p0 / (1.0 + norm2),
        2.0 * p1 / (1.0 + norm2),
        2.0 * p2 / (1.0 + norm2),
        (1.0 - norm2) / (1.0 + norm2),
    )
    x, y, z, w = q[0], q[1], q[2], q[3]
    out[0] = d * x - c * y + b * z + a * w
    out[1] = c * x + d * y - a * z + b * w
    out[2] = -b * x + a * y + d * z + c * w
    out[3] = -a * x - b * y - c * z + d * w


@_jit
def _unscented_prediction(
    offsets: Array,
    quaternion: Array,
    bias: Array,
    rates: Array,
    dt: Array,
    noise: Array,
    weights: Array,
    covariance_weights: Array,
) -> tuple[Array, Array, Array, Array]:
    """:func:`unscented_prediction`'s loop."""
    n, k = offsets.shape[0], rates.shape[0]
    sigma = np.empty((n, 4))
    sigma_rates = np.empty((n, k, 3))
    for i in range(n):
        perturbed_into(offsets[i, :3], quaternion, sigma[i])  # (U1)
        for j in range(k):
            for a in range(3):
                sigma_rates[i, j, a] = rates[j, a] - (bias[a] + offsets[i, 3 + a])
    propagated = _quaternion_steps(sigma, sigma_rates, dt)  # (U2)
    # error vectors 4 p of each point about the first (quaternion_error_vector)
    x0, y0, z0, w0 = -propagated[0, 0], -propagated[0, 1], -propagated[0, 2], propagated[0, 3]
    points = np.empty((n, 6))
    for i in range(n):
        x, y, z, w = propagated[i, 0], propagated[i, 1], propagated[i, 2], propagated[i, 3]
        e = (
            w * x0 - z * y0 + y * z0 + x * w0,
            z * x0 + w * y0 - x * z0 + y * w0,
            -y * x0 + x * y0 + w * z0 + z * w0,
            -x * x0 - y * y0 - z * z0 + w * w0,
        )
        sign = math.copysign(1.0, e[3])
        for a in range(3):
            points[i, a] = 4.0 * (sign * e[a] / (1.0 + sign * e[3]))
            points[i, 3 + a] = offsets[i, 3 + a]
    mean = weights @ points  # (U3)
    spread = points - mean
    centred = np.empty((k, 3))
    for j in range(k):
        for a in range(3):
            centred[j, a] = rates[j, a] - bias[a]
    interval, _ = _covariance_steps(np.zeros((6, 6)), centred, dt, noise)
    covariance = (covariance_weights * spread.T) @ spread + interval  # (U4)
    # carried to the folded attitude: T P T^T, T = blockdiag(J(mean), I) (error_jacobian)
    p0, p1, p2 = mean[0] / 4.0, mean[1] / 4.0, mean[2] / 4.0
    norm2 = p0 * p0 + p1 * p1 + p2 * p2
    s, d = 1.0 - norm2, (1.0 + norm2) ** 2
    reset = np.eye(6)
    reset[0, 0], reset[0, 1], reset[0, 2] = (
        (s + 2 * p0 * p0) / d,
        (-2 * p2 + 2 * p0 * p1) / d,
        (2 * p1 + 2 * p0 * p2) / d,
    )
    reset[1, 0], reset[1, 1], reset[1, 2] = (
        (2 * p2 + 2 * p0 * p1) / d,
        (s + 2 * p1 * p1) / d,
        (-2 * p0 + 2 * p1 * p2) / d,
    )
    reset[2, 0], reset[2, 1], reset[2, 2] = (
        (-2 * p1 + 2 * p0 * p2) / d,
        (2 * p0 + 2 * p1 * p2) / d,
        (s + 2 * p2 * p2) / d,
    )
    covariance = reset @ covariance @ reset.T
    folded = np.empty(4)
    perturbed_into(mean[:3], propagated[0], folded)  # (U5)
    return folded, mean, covariance, spread


# Warm-ups (attopt.formulations.kernels.WARM_UPS): one step of each loop.
_IDENTITY = np.array([[0.0, 0.0, 0.0, 1.0]])
register_warm_up(
    "filters.covariance_steps",
    lambda: covariance_steps(np.eye(6), np.zeros((1, 3)), np.ones(1), np.zeros((1, 6, 6))),
)
register_warm_up(
    "filters.quaternion_steps",
    lambda: quaternion_steps(_IDENTITY, np.zeros((1, 1, 3)), np.ones(1)),
)
register_warm_up(
    "filters.unscented_prediction",
    lambda: unscented_prediction(
        np.zeros((13, 6)),
        _IDENTITY[0],
        np.zeros(3),
        np.zeros((1, 3)),
        np.ones(1),
        np.zeros((1, 6, 6)),
    ),
)
