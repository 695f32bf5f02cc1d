"""USQUE's measurement update for unit vectors as one call of machine code.

:func:`attopt.solvers.filters.usque.update` is the unscented update (U6)-(U9), iterated
as the posterior linearisation filter: the 13 sigma attitudes' predictions, the
weighted innovation, the gate, the statistical regression ``h ~ H x + b`` with its
residual covariance, the gain, and the reset.  In numpy that is some fifty small array
calls and scipy ``Rotation`` objects per pass.  :func:`compiled_update` runs the same
steps in the same order as one numba call, as
:mod:`attopt.solvers.filters.vector_update` does for the MEKF, whose pieces it shares:
each sigma point's prediction is the measurement's compiled CasADi kernel called through
its C entry point (:mod:`attopt.formulations.kernel_calls`), and the gate, gain and
error reset are the compiled loops of the other filter modules.

It serves the same measurements (:func:`~attopt.solvers.filters.vector_update.served`: a
``VectorMeasurement`` with per-vector sigmas, alone or inside a
``ReferencedMeasurement``, without offsets or Huber weights); :func:`compiled_update`
returns ``None`` for anything else, for interpreted kernels, for a covariance whose
Cholesky factor does not exist (the numpy path repairs it first) and where no C compiler
built the kernel, and USQUE then runs its numpy path,
:func:`attopt.solvers.filters.usque.update_reference`, which stays the reference
(``tests/test_vector_update.py``).

Example::

    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> from attopt import FilterOptions, VectorMeasurement
    >>> from attopt.solvers.filters.usque import COVARIANCE_WEIGHTS, LAMBDA, WEIGHTS
    >>> truth = Rotation.from_rotvec([0.02, -0.01, 0.03])
    >>> reference = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    >>> m = VectorMeasurement(truth.apply(reference), reference, 1e-3)
    >>> out = compiled_update(Rotation.identity(), np.zeros(3), np.eye(6) * 1e-3, m,
    ...                       FilterOptions(), (WEIGHTS, COVARIANCE_WEIGHTS, LAMBDA))
    >>> bool(np.linalg.norm((out[0] * truth.inv()).as_rotvec()) < 1e-4)
    True
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.geodesic import _geodesic_rows
from attopt.formulations.kernel_calls import Buffers
from attopt.formulations.kernels import register_warm_up
from attopt.solvers.filters.common import STATE_SIZE, FilterOptions, repair_covariance
from attopt.solvers.filters.update_kernels import (
    _block_nis,
    _information_gain,
    _smallest_attitude_variance,
)
from attopt.solvers.filters.vector_update import (
    COUNTS,
    NO_ROWS,
    NOT_FINITE,
    REFERENCE,
    UPDATED,
    Epoch,
    Layout,
    Settings,
    _count_blocks,
    _gain_step,
    _inverse,
    _lost_rows,
    _members,
    _perturbed,
    _predict,
    _relinearised,
    _usable_rows,
    _where,
    carried,
    run_loop,
)

Array = NDArray[np.float64]
Weights = tuple[Array, Array, float]
"""USQUE's mean weights, covariance weights and ``lambda``
(:data:`attopt.solvers.filters.usque.WEIGHTS`, ``COVARIANCE_WEIGHTS``, ``LAMBDA``)."""

_jit = njit(cache=True, error_model="numpy")
"""numba's compilation, cached on disk, with numpy's float semantics."""


def compiled_update(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    measurement: AttitudeMeasurement,
    options: FilterOptions,
    weights: Weights,
) -> tuple[Rotation, Array, Array, dict[str, float], Array] | None:
    """:func:`attopt.solvers.filters.usque.update` of a unit-vector ``measurement``
    without offsets, as one compiled call (module docstring): the same results, or
    ``None`` where this path does not apply and the numpy path must run."""
    outcome = run_loop(
        _update, "USQUE's vector update", attitude, covariance, measurement, options, *weights
    )
    if outcome is None:
        return None
    status, quaternion, state, posterior, counts = outcome
    increment = state[STATE_SIZE:]
    if status == NO_ROWS:
        return attitude, bias, covariance, counts, increment
    if status == NOT_FINITE:
        return attitude, bias, np.full_like(covariance, np.nan), counts, increment
    posterior, repaired = repair_covariance(posterior)
    counts["covariance_repairs"] += float(repaired)
    estimate = Rotation.from_quat(quaternion)
    return estimate, bias + state[3:STATE_SIZE], posterior, counts, increment


@_jit
def _update(
    kernel: Any,
    buffers: Buffers,
    layout: Layout,
    epoch: Epoch,
    settings: Settings,
    weights: Array,
    covariance_weights: Array,
    lam: float,
) -> tuple[int, Array, Array, Array, Array]:
    """:func:`compiled_update`'s loop: :func:`attopt.solvers.filters.usque.update`'s
    numpy path, step for step, for variances and no offsets (returns the outcome, the
    quaternion, the error state, the posterior carried to the reset attitude before its
    repair, and :data:`~attopt.solvers.filters.vector_update.COUNTS`)."""
    quaternion, covariance, z, variances, blocks, parameters = epoch
    gating, threshold, max_iterations, fraction = settings
    n, m, points = covariance.shape[0], z.size, weights.size
    counts = np.zeros(len(COUNTS))
    counts[3] = np.nan
    state = np.zeros(n)
    sigma = _sigma_offsets(covariance, lam)
    values = (np.empty(9), np.empty(layout[1].size), np.empty(layout[2].size))
    predicted, innovations = np.empty((points, m)), np.empty((points, m))
    if not _sigma_innovations(
        kernel, buffers, layout, quaternion, state, sigma, parameters, values, z,
        predicted, innovations,
    ):  # fmt: skip
        return REFERENCE, quaternion, state, covariance, counts
    keep, n_nan, n_unpredictable = _usable_rows(z, predicted, innovations, blocks)
    counts[1], counts[2] = n_nan, n_unpredictable
    rows = _where(keep)
    if rows.size == 0:
        return NO_ROWS, quaternion, state, covariance, counts
    used = innovations[:, rows]
    nu = _weighted_mean(weights, used)  # (U6)
    accepted = np.ones(rows.size, dtype=np.bool_)
    if gating:  # (U7) per block
        factor = _deviations(nu, used)
        nis, _ = _block_nis(
            nu, factor, np.diag(covariance_weights), variances[rows].reshape(1, -1), False,
            _members(blocks[rows]),
        )  # fmt: skip
        accepted = nis <= threshold  # a NaN NIS is rejected too
    counts[0] = _count_blocks(blocks[rows[~accepted]])
    if not accepted.any():
        return NO_ROWS, quaternion, state, covariance, counts
    rows, nu, used = rows[accepted], nu[accepted], used[:, accepted]
    counts[5] = _count_blocks(blocks[rows])
    posterior = covariance
    information = _inverse(covariance)
    for iteration in range(max_iterations):
        if iteration > 0:
            if not (np.isfinite(state).all() and np.isfinite(posterior).all()):
                break
            sigma = _sigma_offsets(posterior[:STATE_SIZE, :STATE_SIZE].copy(), lam)
            if not _sigma_innovations(
                kernel, buffers, layout, quaternion, state, sigma, parameters, values, z,
                predicted, innovations,
            ):  # fmt: skip
                return REFERENCE, quaternion, state, covariance, counts
            used = innovations[:, rows]
            lost = _lost_rows(used, blocks[rows])
            if lost.any():  # relinearised: drop blocks the model can no longer predict
                n_lost = _count_blocks(blocks[rows[lost]])
                counts[2] += n_lost
                counts[5] -= n_lost
                rows, used = rows[~lost], used[:, ~lost]
                if rows.size == 0:
                    break
            nu = _weighted_mean(weights, used)
        h, omega = _regression(nu, used, sigma, covariance_weights, lam, n)  # (U7)-(U8)
        noise = variances[rows] + omega
        relinearised = _relinearised(nu, h, state)
        gain, nis_value, posterior = _information_gain(information, h, noise, relinearised)
        step = _gain_step(gain, relinearised, state)
        state = state + step
        counts[7] = iteration + 1
        counts[3], counts[4] = nis_value, rows.size
        exact = omega.sum() <= fraction * variances[rows].sum()
        variance = _smallest_attitude_variance(posterior[:3, :3].copy())
        smallest = math.sqrt(0.0 if 0.0 > variance else variance)
        if 0.5 * (step[:3] @ step[:3]) <= fraction * smallest and exact:
            break
    if not (np.isfinite(state).all() and np.isfinite(posterior).all()):
        return NOT_FINITE, quaternion, state, posterior, counts
    return UPDATED, _perturbed(state, quaternion), state, carried(posterior, state), counts


@_jit
def _sigma_offsets(covariance: Array, lam: float) -> Array:
    """:func:`attopt.solvers.filters.usque.sigma_offsets`' offsets, ``(13, 6)``; numba's
    ``LinAlgError`` when ``(n + lambda) P`` has no Cholesky factor (the caller's numpy
    path then repairs it)."""
    n = covariance.shape[0]
    root = np.linalg.cholesky((n + lam) * covariance)  # LinAlgError if not positive
    offsets = np.zeros((2 * n + 1, n))
    offsets[1 : n + 1] = root.T
    offsets[n + 1 :] = -root.T
    return offsets


@_jit
def _sigma_innovations(
    kernel: Any,
    buffers: Buffers,
    layout: Layout,
    quaternion: Array,
    state: Array,
    sigma: Array,
    parameters: Array,
    values: tuple[Array, Array, Array],
    z: Array,
    predicted: Array,
    innovations: Array,
) -> bool:
    """Each sigma attitude's prediction (``state + sigma_i`` applied to ``quaternion``)
    and its geodesic innovation into ``predicted`` and ``innovations``; whether every
    kernel call succeeded."""
    m = z.size
    jacobian = np.empty((m, 3))
    point = np.empty(3)
    for i in range(sigma.shape[0]):
        for a in range(3):
            point[a] = state[a] + sigma[i, a]
        attitude = _perturbed(point, quaternion)
        if _predict(kernel, buffers, layout, attitude, parameters, values, predicted[i], jacobian):
            return False
    innovations[:, :] = _geodesic_rows(predicted, z)
    return True


@_jit
def _weighted_mean(weights: Array, points: Array) -> Array:
    """``sum_i w_i x_i`` of the rows ``x_i`` of ``points`` (``weights @ points``)."""
    out = np.zeros(points.shape[1])
    for i in range(points.shape[0]):
        for j in range(points.shape[1]):
            out[j] += weights[i] * points[i, j]
    return out


@_jit
def _deviations(mean: Array, points: Array) -> Array:
    """``mean - x_i`` for each row ``x_i`` of ``points``."""
    out = np.empty(points.shape)
    for i in range(points.shape[0]):
        for j in range(points.shape[1]):
            out[i, j] = mean[j] - points[i, j]
    return out


@_jit
def _regression(
    nu: Array, innovations: Array, sigma: Array, covariance_weights: Array, lam: float, n: int
) -> tuple[Array, Array]:
    """:func:`attopt.solvers.filters.usque.regression` of the deviations ``nu -
    innovations`` on the sigma points: ``H`` ``(k, n)`` (zero beyond the 6 states the
    points span) and the residual variances ``omega``."""
    size = sigma.shape[1]
    points, k = innovations.shape
    deviation = _deviations(nu, innovations)
    differences = np.empty((size, k))
    for p in range(size):
        for j in range(k):
            differences[p, j] = deviation[1 + p, j] - deviation[1 + size + p, j]
    solved = np.linalg.solve(sigma[1 : size + 1].copy(), differences)
    h = np.zeros((k, n))
    for j in range(k):
        for p in range(size):
            h[j, p] = 0.5 * solved[p, j]
    omega = np.empty(k)
    for j in range(k):
        spread = 0.0
        for p in range(points):
            spread += covariance_weights[p] * deviation[p, j] ** 2
        total = 0.0
        for p in range(size):
            total += differences[p, j] ** 2
        omega[j] = spread - total / (4.0 * (size + lam))
    return h, omega


def _warm_up() -> None:
    """A two-vector update of a 6-state USQUE (the callers' types)."""
    from attopt.formulations.attitude_measurement import VectorMeasurement
    from attopt.solvers.filters.usque import COVARIANCE_WEIGHTS, LAMBDA, WEIGHTS

    reference = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    measurement = VectorMeasurement(reference, reference, 1e-3)
    weights = (WEIGHTS, COVARIANCE_WEIGHTS, LAMBDA)
    compiled_update(
        Rotation.identity(), np.zeros(3), np.eye(6), measurement, FilterOptions(), weights
    )


register_warm_up("vectors.usque_update", _warm_up)
