"""The MEKF's measurement update for unit vectors as one call of machine code.

:func:`attopt.solvers.filters.mekf.update` is one iterated EKF update: predict the
measurement and its Jacobian at the estimate, the geodesic innovation, the gate, the
Gauss-Newton steps on the MAP cost with their backtracking, the information-form gain,
the Joseph form and the reset.  In numpy that is some forty small array calls and two
scipy ``Rotation`` objects per iteration: 0.4-0.5 ms an epoch for a magnetometer and a
Sun sensor, most of it Python, paid 6,000 times on a ``wahba-mag-sun`` pass by every
MEKF and RTS run.  :func:`compiled_update` runs the same algorithm, step for step, as
one numba call: the measurement model and its AD Jacobian are the measurement's own
compiled CasADi kernel, called from the loop through its C entry point
(:mod:`attopt.formulations.kernel_calls`), so the model keeps its single symbolic
definition; the gate, gain, definiteness test and error reset are the compiled loops of
:mod:`attopt.solvers.filters.update_kernels`, :mod:`attopt.solvers.filters.compiled` and
:mod:`attopt.formulations.geodesic`.  Written with numba because the point is the
per-call cost of many small steps, which numpy cannot lower.

It serves :class:`~attopt.formulations.attitude_measurement.VectorMeasurement` with
variances (``sigma`` per vector), alone or inside a
:class:`~attopt.formulations.attitude_measurement.ReferencedMeasurement`, without
transmitter offsets and without the Huber weights (``FilterOptions.huber_threshold``);
:func:`compiled_update` returns ``None`` for anything else, for interpreted kernels
(``ATTOPT_KERNELS=interpreted``) and where no C compiler built the kernel, and the MEKF
then runs its numpy path, :func:`attopt.solvers.filters.mekf.update_reference`, which
stays the reference (``tests/test_vector_update.py``: the same counts, and the attitude,
bias and covariance to round-off as the update's conditioning amplifies it, 1e-14 rad in
steady state, over random updates that gate, iterate and backtrack).  USQUE's update
(:mod:`attopt.solvers.filters.vector_unscented_update`) shares this module's pieces:
:func:`served`, :func:`run_loop` and the small loops.

Example::

    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> from attopt import FilterOptions, VectorMeasurement
    >>> truth = Rotation.from_rotvec([0.2, -0.1, 0.3])
    >>> reference = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    >>> m = VectorMeasurement(truth.apply(reference), reference, 1e-3)
    >>> out = compiled_update(Rotation.identity(), np.zeros(3), np.eye(6) * 0.1, m,
    ...                       FilterOptions(), max_halvings=8)
    >>> error = (out[0] * truth.inv()).as_rotvec()  # 21 deg corrected, iterating
    >>> bool(np.linalg.norm(error) < 1e-4), out[3]["update_iterations"] > 1
    (True, True)
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    ReferencedMeasurement,
    VectorMeasurement,
)
from attopt.formulations.geodesic import _geodesic_rows
from attopt.formulations.kernel_calls import Buffers, KernelCall, evaluate, kernel_call
from attopt.formulations.kernels import compiled_loops, first_call, register_warm_up
from attopt.solvers.filters.common import (
    STATE_SIZE,
    FilterOptions,
    gate_threshold,
    repair_covariance,
)
from attopt.solvers.filters.compiled import perturbed_into
from attopt.solvers.filters.update_kernels import (
    _block_nis,
    _information_gain,
    _smallest_attitude_variance,
    _symmetric_positive,
)

Array = NDArray[np.float64]
Layout = tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]
"""A vector kernel's parameter sizes (its inputs after the attitude), the rows of ``h``'s
nonzeros and the rows and columns of its Jacobian's (:func:`_predict`)."""
Epoch = tuple[Array, Array, Array, Array, NDArray[np.intp], Array]
"""What a compiled update reads of the epoch: the estimate's quaternion, the covariance,
the measured vectors, their variances, their block labels and the kernel's parameters."""
Settings = tuple[bool, float, int, float]
"""A compiled update's options: whether to gate, the gate's threshold, the most passes and
the relinearisation fraction (``FilterOptions``)."""

_jit = njit(cache=True, error_model="numpy")
"""numba's compilation, cached on disk, with numpy's float semantics."""

COUNTS = (
    "n_gated",
    "n_nan",
    "n_unpredictable",
    "nis",
    "nis_dof",
    "n_used",
    "covariance_repairs",
    "update_iterations",
)
"""The update's counts, in the order of the loop's ``counts`` array (and of the numpy
path's dictionary, which adds ``n_downweighted``, always 0 here)."""
UPDATED, NO_ROWS, NOT_FINITE, REFERENCE = 0, 1, 2, 3
"""The loop's outcomes: updated; every vector left out (the prior is kept); a step that
is not finite (the bias becomes NaN and the caller flags the epoch); a case the numpy
path decides (a kernel that failed, a cost that is not a number)."""


def compiled_update(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    measurement: AttitudeMeasurement,
    options: FilterOptions,
    max_halvings: int,
) -> tuple[Rotation, Array, Array, dict[str, float], Array] | None:
    """:func:`attopt.solvers.filters.mekf.update` of a unit-vector ``measurement``
    without offsets, as one compiled call (module docstring): the same results, or
    ``None`` where this path does not apply and the numpy path must run."""
    label = "the MEKF's vector update"
    outcome = run_loop(_update, label, attitude, covariance, measurement, options, max_halvings)
    if outcome is None:
        return None
    status, quaternion, state, posterior, counts = outcome
    if status == NO_ROWS:
        return attitude, bias, covariance, counts, state[STATE_SIZE:]
    if status == NOT_FINITE:
        return attitude, np.full(3, np.nan), covariance, counts, state[STATE_SIZE:]
    if counts["covariance_repairs"]:  # not positive definite: floor its eigenvalues
        posterior, _ = repair_covariance(posterior)
    estimate = Rotation.from_quat(quaternion)
    return estimate, bias + state[3:STATE_SIZE], posterior, counts, state[STATE_SIZE:]


def run_loop(
    loop: Any,
    label: str,
    attitude: Rotation,
    covariance: Array,
    measurement: AttitudeMeasurement,
    options: FilterOptions,
    *extra: object,
) -> tuple[int, Array, Array, Array, dict[str, float]] | None:
    """Call a compiled update ``loop`` (this module's, or
    :mod:`attopt.solvers.filters.vector_unscented_update`'s) on a measurement it serves
    (:func:`served`): its outcome, quaternion, error state, posterior and counts (a
    dictionary in the numpy path's order), or ``None`` where the numpy path must run (not
    served, a covariance LAPACK cannot factor, an outcome it decides).  ``extra`` follows
    the arguments the loops share."""
    inputs = served(measurement, covariance, options)
    if inputs is None:
        return None
    call, layout, parameters = inputs
    gating = options.gate_probability < 1.0
    try:
        status, quaternion, state, posterior, counts = first_call(
            loop,
            label,
            call.function,
            call.buffers,
            layout,
            (
                attitude.as_quat(),
                np.ascontiguousarray(covariance, dtype=float),
                measurement.z,
                np.ascontiguousarray(measurement.noise_covariance, dtype=float),
                np.ascontiguousarray(measurement.blocks, dtype=np.intp),
                parameters,
            ),
            (
                gating,
                _gate_threshold(options.gate_probability) if gating else np.inf,
                options.max_update_iterations,
                options.relinearise_fraction,
            ),
            *extra,
        )
    except np.linalg.LinAlgError:  # numpy's inverse or Cholesky factor of a matrix LAPACK
        return None  # cannot factor is NaN, raises or is repaired: the numpy path decides
    if status == REFERENCE:
        return None
    counts = dict(zip(COUNTS, counts.tolist(), strict=True)) | {"n_downweighted": 0.0}
    return status, quaternion, state, posterior, counts


def served(
    measurement: AttitudeMeasurement, covariance: Array, options: FilterOptions
) -> tuple[KernelCall, Layout, Array] | None:
    """Whether the compiled updates serve ``measurement`` (module docstring): its kernel
    call, the kernel's :data:`Layout` and the parameters' nonzeros (column-major, one
    after another), or ``None``."""
    inner = measurement.inner if type(measurement) is ReferencedMeasurement else measurement
    if (
        type(inner) is not VectorMeasurement
        or measurement.noise_covariance.ndim != 1
        or options.huber_threshold is not None
        or measurement.z.size == 0
        or not compiled_loops()
        or not np.isfinite(covariance).all()
    ):
        return None
    model = measurement.symbolic_model()
    call = kernel_call(model.function)
    if call is None or not call.dense_inputs or model.rows is not None:
        return None
    layout = call.input_sizes[1:], call.outputs[0][0], *call.outputs[1]
    return call, layout, np.concatenate([p.ravel(order="F") for p in model.parameters])


@lru_cache(maxsize=16)
def _gate_threshold(probability: float) -> float:
    """The gate of one vector's three rows (:func:`~attopt.solvers.filters.common.gate`)."""
    return gate_threshold(probability, 3)


@_jit
def _update(
    kernel: Any,
    buffers: Buffers,
    layout: Layout,
    epoch: Epoch,
    settings: Settings,
    max_halvings: int,
) -> tuple[int, Array, Array, Array, Array]:
    """:func:`compiled_update`'s loop: :func:`attopt.solvers.filters.mekf.update`'s
    numpy path, step for step, for variances and no offsets (returns the outcome, the
    quaternion, the error state, the posterior before any eigenvalue repair and
    :data:`COUNTS`, ``covariance_repairs`` 1 where that repair is due).  The matrix
    algebra is written as loops in small functions: numba compiles them in a fraction of
    the time of the equivalent array expressions."""
    quaternion, covariance, z, variances, blocks, parameters = epoch
    gating, threshold, max_iterations, fraction = settings
    n, m = covariance.shape[0], z.size
    counts = np.zeros(len(COUNTS))
    counts[3] = np.nan
    state = np.zeros(n)
    values = (np.empty(9), np.empty(layout[1].size), np.empty(layout[2].size))
    predicted, jacobian = np.empty(m), np.empty((m, 3))
    current = quaternion.copy()
    information = _inverse(covariance)
    accepted_state, accepted_cost = state.copy(), np.inf
    trial_step, halvings = np.zeros(n), 0
    rows = np.arange(m)
    gain, h, gain_variances = np.zeros((n, 0)), np.zeros((0, n)), np.zeros(0)
    for iteration in range(max_iterations):
        status = _predict(kernel, buffers, layout, current, parameters, values, predicted, jacobian)
        if status != 0:
            return REFERENCE, quaternion, state, covariance, counts
        innovation = _geodesic_rows(predicted.reshape(1, m), z)[0]
        carry = np.eye(3) if iteration == 0 else _error_jacobian(state)
        counts[7] = iteration + 1
        if iteration == 0:
            keep, n_nan, n_unpredictable = _usable_rows(
                z, predicted.reshape(1, m), innovation.reshape(1, m), blocks
            )
            counts[1], counts[2] = n_nan, n_unpredictable
            rows = _where(keep)
            accepted = np.ones(rows.size, dtype=np.bool_)
            if gating and rows.size:
                factor = _state_rows(jacobian, carry, rows, n).T.copy()
                nis, _ = _block_nis(
                    innovation[rows], factor, covariance, variances[rows].reshape(1, -1), False,
                    _members(blocks[rows]),
                )  # fmt: skip
                accepted = nis <= threshold  # a NaN NIS is rejected too
            counts[0] = _count_blocks(blocks[rows[~accepted]])
            rows = rows[accepted]
            if rows.size == 0:
                return NO_ROWS, quaternion, state, covariance, counts
        else:  # relinearised: drop blocks the model can no longer predict
            lost = _lost_rows(innovation[rows].reshape(1, rows.size), blocks[rows])
            if lost.any():
                counts[2] += _count_blocks(blocks[rows[lost]])
                rows = rows[~lost]
                accepted_cost = np.inf  # another sum: costs are not comparable
                if rows.size == 0:
                    break
        nu = innovation[rows]
        cost = _map_cost(nu, variances[rows], state, information)
        if not cost <= accepted_cost:  # backtrack: halve the last step
            if halvings == max_halvings or not math.isfinite(accepted_cost):
                if h.shape[0] == 0:  # no step taken yet: the numpy path decides
                    return REFERENCE, quaternion, state, covariance, counts
                state = accepted_state.copy()  # keep the last accepted point
                break
            halvings += 1
            trial_step = 0.5 * trial_step
            state = accepted_state + trial_step
            current = _perturbed(state, quaternion)
            continue
        accepted_state, accepted_cost, halvings = state.copy(), cost, 0
        h, gain_variances = _state_rows(jacobian, carry, rows, n), variances[rows]
        relinearised = nu + h @ state
        gain, nis_value, posterior = _information_gain(information, h, gain_variances, relinearised)
        trial_step = gain @ relinearised - state
        state = state + trial_step
        counts[3], counts[4] = nis_value, rows.size
        if not np.isfinite(state).all():
            return NOT_FINITE, quaternion, state, covariance, counts
        variance = _smallest_attitude_variance(posterior[:3, :3].copy())
        smallest = math.sqrt(0.0 if 0.0 > variance else variance)
        if 0.5 * (trial_step[:3] @ trial_step[:3]) <= fraction * smallest:
            break
        current = _perturbed(state, quaternion)
    updated = _joseph_reset(covariance, gain, h, gain_variances, state)
    posterior, positive = _symmetric_positive(updated)
    counts[5] = _count_blocks(blocks[rows])
    counts[6] = 0.0 if positive else 1.0
    return UPDATED, _perturbed(state, quaternion), state, posterior, counts


@_jit
def _inverse(matrix: Array) -> Array:
    """``matrix^-1`` (LAPACK, as numpy's)."""
    return np.linalg.inv(matrix)


@_jit
def _where(keep: NDArray[np.bool_]) -> NDArray[np.intp]:
    """The indices of the true entries of ``keep`` (``np.flatnonzero``)."""
    out = np.empty(keep.size, dtype=np.intp)
    k = 0
    for i in range(keep.size):
        if keep[i]:
            out[k] = i
            k += 1
    return out[:k]


@_jit
def _state_rows(jacobian: Array, carry: Array, rows: NDArray[np.intp], n: int) -> Array:
    """``H``: the ``rows`` of the body-frame Jacobian times ``carry`` (the error
    Jacobian at the iterate) in the attitude columns, zeros in the other ``n - 3``."""
    h = np.zeros((rows.size, n))
    for i in range(rows.size):
        for b in range(3):
            total = 0.0
            for a in range(3):
                total += jacobian[rows[i], a] * carry[a, b]
            h[i, b] = total
    return h


@_jit
def _map_cost(nu: Array, variances: Array, state: Array, information: Array) -> float:
    """The MAP cost ``(1/2) (nu^T R^-1 nu + x^T P^-1 x)``."""
    total = 0.0
    for i in range(nu.size):
        total += nu[i] * (nu[i] / variances[i])
    n = state.size
    for a in range(n):
        for b in range(n):
            total += state[a] * information[a, b] * state[b]
    return 0.5 * total


@_jit
def _joseph_reset(
    covariance: Array, gain: Array, h: Array, variances: Array, state: Array
) -> Array:
    """The Joseph form ``(I - K H) P (I - K H)^T + K R K^T`` carried to the reset
    attitude, ``T P T^T`` with ``T = blockdiag(J(x), I)``
    (:func:`attopt.solvers.filters.common.error_jacobian`)."""
    n, k = gain.shape
    joseph = np.zeros((n, n))  # I - K H
    for a in range(n):
        for b in range(n):
            total = 1.0 if a == b else 0.0
            for i in range(k):
                total -= gain[a, i] * h[i, b]
            joseph[a, b] = total
    left = np.zeros((n, n))  # (I - K H) P
    for a in range(n):
        for c in range(n):
            for b in range(n):
                left[a, b] += joseph[a, c] * covariance[c, b]
    updated = np.zeros((n, n))  # ... (I - K H)^T + K R K^T
    for a in range(n):
        for b in range(n):
            total = 0.0
            for c in range(n):
                total += left[a, c] * joseph[b, c]
            for i in range(k):
                total += gain[a, i] * variances[i] * gain[b, i]
            updated[a, b] = total
    return carried(updated, state)


@_jit
def carried(covariance: Array, state: Array) -> Array:
    """``T P T^T`` with ``T = blockdiag(J(x), I)``: the covariance of the error about the
    attitude reset by ``x`` (:func:`attopt.solvers.filters.usque.carried`)."""
    n = covariance.shape[0]
    carry = _error_jacobian(state)
    rows = covariance.copy()
    for a in range(3):  # T P: the attitude rows
        for b in range(n):
            rows[a, b] = (
                carry[a, 0] * covariance[0, b]
                + carry[a, 1] * covariance[1, b]
                + carry[a, 2] * covariance[2, b]
            )
    out = rows.copy()
    for a in range(n):  # (T P) T^T: the attitude columns
        for b in range(3):
            out[a, b] = (
                rows[a, 0] * carry[b, 0] + rows[a, 1] * carry[b, 1] + rows[a, 2] * carry[b, 2]
            )
    return out


@_jit
def _relinearised(nu: Array, h: Array, state: Array) -> Array:
    """``nu + H x``: the innovation relinearised at the iterate ``x``."""
    out = nu.copy()
    for i in range(nu.size):
        for a in range(state.size):
            out[i] += h[i, a] * state[a]
    return out


@_jit
def _gain_step(gain: Array, relinearised: Array, state: Array) -> Array:
    """``K (nu + H x) - x``: the Gauss-Newton step from the iterate ``x``."""
    step = -state
    for a in range(state.size):
        for i in range(relinearised.size):
            step[a] += gain[a, i] * relinearised[i]
    return step


@_jit
def _predict(
    kernel: Any,
    buffers: Buffers,
    layout: Layout,
    quaternion: Array,
    parameters: Array,
    values: tuple[Array, Array, Array],
    predicted: Array,
    jacobian: Array,
) -> int:
    """The model ``h`` and its body-frame Jacobian at ``quaternion`` into ``predicted``
    and ``jacobian``, by the measurement's kernel (inputs: the attitude matrix, then the
    parameters, each column-major, of the sizes ``layout[0]``; ``values`` holds the matrix
    and the outputs' nonzeros, scattered by ``layout``); returns the kernel's status."""
    sizes, h_rows, j_rows, j_columns = layout
    matrix, h_values, j_values = values
    arguments, results = buffers[0], buffers[1]
    _attitude_matrix(quaternion, matrix)
    arguments[0] = matrix.ctypes.data
    offset = 0
    for i in range(sizes.size):
        arguments[1 + i] = parameters.ctypes.data + 8 * offset
        offset += sizes[i]
    results[0] = h_values.ctypes.data
    results[1] = j_values.ctypes.data
    status = evaluate(kernel, buffers)
    predicted[:] = 0.0
    jacobian[:, :] = 0.0
    for e in range(h_rows.size):
        predicted[h_rows[e]] = h_values[e]
    for e in range(j_rows.size):
        jacobian[j_rows[e], j_columns[e]] = j_values[e]
    return status


@_jit
def _attitude_matrix(q: Array, out: Array) -> None:
    """``out`` = the attitude matrix of the unit scalar-last quaternion ``q``, column by
    column (scipy's ``Rotation.as_matrix``)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    out[0], out[1], out[2] = x2 - y2 - z2 + w2, 2.0 * (xy + zw), 2.0 * (xz - yw)
    out[3], out[4], out[5] = 2.0 * (xy - zw), -x2 + y2 - z2 + w2, 2.0 * (yz + xw)
    out[6], out[7], out[8] = 2.0 * (xz + yw), 2.0 * (yz - xw), -x2 - y2 + z2 + w2


@_jit
def _perturbed(delta: Array, reference: Array) -> Array:
    """The unit quaternion of ``delta`` applied to ``reference``
    (:func:`attopt.solvers.filters.common.apply_error`, normalised as
    ``Rotation.from_quat`` normalises)."""
    out = np.empty(4)
    perturbed_into(delta, reference, out)
    return out / math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2 + out[3] ** 2)


@_jit
def _error_jacobian(delta: Array) -> Array:
    """:func:`attopt.solvers.filters.common.error_jacobian` of ``delta``'s first three
    entries (its closed form)."""
    x, y, z = delta[0] / 4.0, delta[1] / 4.0, delta[2] / 4.0
    norm2 = x * x + y * y + z * z
    a, d = 1.0 - norm2, (1.0 + norm2) ** 2
    xy, xz, yz = 2.0 * x * y, 2.0 * x * z, 2.0 * y * z
    out = np.empty((3, 3))
    out[0, 0], out[0, 1], out[0, 2] = (a + 2.0 * x * x) / d, (-2.0 * z + xy) / d, (2.0 * y + xz) / d
    out[1, 0], out[1, 1], out[1, 2] = (2.0 * z + xy) / d, (a + 2.0 * y * y) / d, (-2.0 * x + yz) / d
    out[2, 0], out[2, 1], out[2, 2] = (-2.0 * y + xz) / d, (2.0 * x + yz) / d, (a + 2.0 * z * z) / d
    return out


@_jit
def _usable_rows(
    z: Array, predicted: Array, innovations: Array, blocks: NDArray[np.intp]
) -> tuple[NDArray[np.bool_], float, float]:
    """:func:`attopt.solvers.filters.common.usable_rows` over the points (one row of
    ``predicted`` and ``innovations`` for the MEKF, 13 for USQUE's sigma points): whole
    blocks with a finite measured value and finite predictions and innovations at every
    point; the counts of blocks left out for each reason."""
    m = z.size
    bad_z = np.zeros(m, dtype=np.bool_)
    bad_h = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        for j in range(m):
            if blocks[j] != blocks[i]:
                continue
            if not math.isfinite(z[j]):
                bad_z[i] = True
            for p in range(predicted.shape[0]):
                if not (math.isfinite(predicted[p, j]) and math.isfinite(innovations[p, j])):
                    bad_h[i] = True
    unpredictable = bad_h & ~bad_z
    n_nan = float(_count_blocks(blocks[bad_z]))
    return ~(bad_z | bad_h), n_nan, float(_count_blocks(blocks[unpredictable]))


@_jit
def _lost_rows(innovations: Array, blocks: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Per column, whether its block has an innovation that is not finite at some point
    (a row of ``innovations``)."""
    lost = np.zeros(innovations.shape[1], dtype=np.bool_)
    for j in range(innovations.shape[1]):
        for p in range(innovations.shape[0]):
            if not math.isfinite(innovations[p, j]):
                lost |= blocks == blocks[j]
                break
    return lost


@_jit
def _count_blocks(labels: NDArray[np.intp]) -> int:
    """:func:`attopt.solvers.blocks.count_blocks`: the number of distinct labels."""
    count = 0
    for i in range(labels.size):
        first = True
        for j in range(i):
            if labels[j] == labels[i]:
                first = False
                break
        count += first
    return count


@_jit
def _members(labels: NDArray[np.intp]) -> NDArray[np.intp]:
    """:attr:`attopt.solvers.blocks.BlockMembers.members` of ``labels``: per row, the rows
    of its block in order, padded with -1."""
    m = labels.size
    width = 0
    for i in range(m):
        width = max(width, int(np.sum(labels == labels[i])))
    members = np.full((m, width), -1, dtype=np.intp)
    for i in range(m):
        k = 0
        for j in range(m):
            if labels[j] == labels[i]:
                members[i, k] = j
                k += 1
    return members


def _warm_up() -> None:
    """A two-vector update of a 6-state MEKF (the callers' types)."""
    reference = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    measurement = VectorMeasurement(reference, reference, 1e-3)
    compiled_update(Rotation.identity(), np.zeros(3), np.eye(6), measurement, FilterOptions(), 8)


register_warm_up("vectors.mekf_update", _warm_up)
