"""Measurement factors of the smoother: one stacked linear factor per epoch, interface only.

Every measurement is an
:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement` (SNRs of Liu et
al. 2023 eq. 10 / Pimienta-Penalver and Crassidis eq. 7 through
:class:`~attopt.formulations.snr_measurement.SnrMeasurement`, unit vectors, Euler
angles; nothing here is measurement-specific).  At an attitude estimate ``A``
of the epoch's node, ``predict`` gives ``h`` and ``J = dh/d delta`` (CasADi
AD, body-frame error ``exp(delta) A``) for all the epoch's rows at once, and
the factor is the whitened residual of the innovation ``nu = innovation(h)``
(``z - h`` with the model's angle wrapping or tangent-plane projection)::

    e(xi) = -W nu(h(A(xi))),   A(xi) = exp(-xi) A,   de/dxi = -W K,
    K = -(d nu / d h) J        (= J when nu = z - h),

``W = L^-1`` with ``R = L L^T`` the Cholesky factor of the noise covariance
over the epoch's used rows (``W`` is elementwise when ``R`` is diagonal) and
``d nu / d h`` by central differences through ``innovation``
(:func:`innovation_jacobian`).  The sign: ``delta = -xi``
(:mod:`attopt.solvers.smoother.conventions`), so ``dh/dxi = -J``.  The linearisation
``|| -W K xi - W nu ||^2`` is added to the linearised built-in factors as
one ``gtsam.JacobianFactor`` on the epoch's
attitude key, compressed by a QR factorisation of ``[-W K, W nu]`` to at most
three rows (same information, fewer rows to eliminate).  No Python
``CustomFactor`` is involved: GTSAM never calls back into Python, so the cost
per iteration is linear in the pass (``docs/smoother.md``).

Rows (:func:`prepare_factor`, at the initial estimate, once):

* ``R = noise_covariance_at(A_init)`` (``(m,)`` variances or an ``(m, m)``
  matrix; work is linear in the rows for variances), held fixed while the optimiser runs
  (the truncated SNR model's ``R`` depends on the attitude;
  the batch smoother's ``noise_updates`` re-evaluate it at the solution);
* rows with a NaN value or that the model cannot predict are left out
  (:func:`attopt.solvers.filters.common.usable_rows`), counted per block;
* outliers are gated once on the innovation at the initial estimate,
  ``S = J P J^T + R`` with ``P`` the initial estimate's attitude covariance
  (:func:`attopt.solvers.filters.common.gate`, which forms only the diagonal blocks
  of ``S``; the same chi-square gate as the filters), counted;
* ``R`` is block-diagonal over the blocks (true of every implementation):
  the Huber loss and the dropping of blocks rely on it;
* a block that becomes unpredictable at a trial iterate (outside the main
  lobe) is dropped, counted as unpredictable: at once if the step is accepted
  (the costs are compared on the blocks both points predict), and also when
  it is rejected, the step then being solved again without it (as the
  MEKF's iterated update drops such blocks).

Optional robust loss: Huber on the norm ``s`` of each block's whitened
residual, ``rho(s) = s^2 / 2`` for ``s <= k`` and ``k s - k^2 / 2`` beyond,
minimised by iteratively reweighted least squares (weight ``min(1, k / s)``
per block at the current estimate); the blocks down-weighted at the solution
are counted.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    offset_slope_each,
    predict_each,
)
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.kernels import compiled_loops
from attopt.solvers.blocks import BlockMembers, block_structure, count_blocks
from attopt.solvers.filters.common import (
    gate,
    noise_subset,
    usable_rows,
)
from attopt.solvers.robust import huber_cost, huber_weights
from attopt.solvers.smoother.conventions import Array, attitude_key, offset_key
from attopt.solvers.smoother.difference_kernels import chain_rule, perturbed_predictions

COUNTS = ("n_used", "n_gated", "n_nan", "n_unpredictable")
UNIT1 = gtsam.noiseModel.Unit.Create(1)
NO_BLOCKS = np.zeros(0, dtype=np.intp)
"""No block lost (shared, not to be modified)."""
NO_BLOCKS.flags.writeable = False


FD_STEP = 1e-6
"""Relative central-difference step of the innovation's derivative."""


def innovation_jacobian(
    measurement: AttitudeMeasurement,
    predicted: Array,
    jacobian: Array,
    blocks: BlockMembers,
) -> Array:
    """``-d nu / d delta`` ``(m, 3)`` of the innovation ``nu = innovation(h)``.

    Chain rule ``d nu / d delta = (d nu / d h) J``.  The interface gives no
    derivative of ``innovation``: it is taken by central differences, one
    perturbation per row position within a block (a block's innovation
    depends on that block's predictions only), all in one batched call.  For
    ``z - h`` (SNRs) and wrapped angles ``d nu / d h = -I`` and the result is
    ``J``; for unit vectors the tangent-plane projection adds terms of the
    order of the residual, which a Gauss-Newton step with ``J`` alone would
    leave out, moving its fixed point off the minimum of the cost by
    ``O(sigma^2)``.  The arithmetic around the ``innovation`` call is compiled
    (:mod:`attopt.solvers.smoother.difference_kernels`) unless kernels are interpreted.
    """
    m, size = blocks.members.shape
    if compiled_loops():  # the same arithmetic in two compiled calls
        perturbed, step = perturbed_predictions(predicted, blocks.position, size, FD_STEP)
        with np.errstate(invalid="ignore"):
            nu = measurement.innovation(perturbed)
        return chain_rule(nu, step, blocks.valid, blocks.source, jacobian)
    step = FD_STEP * np.maximum(1.0, np.abs(predicted))
    signed = np.zeros((size, 2, m))
    signed[blocks.position, :, np.arange(m)] = step[:, None] * np.array([1.0, -1.0])
    with np.errstate(invalid="ignore"):
        nu = measurement.innovation(predicted + signed.reshape(2 * size, m)).reshape(size, 2, m)
    # d nu_i / d h_j for the j at position r of row i's block: (nu[r, +] - nu[r, -])_i / 2 step_j
    difference = (nu[:, 0] - nu[:, 1]).T
    derivative = np.where(blocks.valid, difference / (2.0 * step[blocks.source]), 0.0)
    # the padding's rows left out (a NaN Jacobian there must not reach a smaller block)
    chained = np.where(blocks.valid[..., None], jacobian[blocks.source], 0.0)
    return -np.einsum("ir,irk->ik", derivative, chained)


class EpochFactor:
    """The used rows of one epoch's measurement and their current linearisation.

    ``offset_index`` ``(m,)``: per row, the index of its transmitter's offset
    variable in the pass (``None``: offsets not modelled; module docstring).
    """

    def __init__(
        self,
        node: int,
        measurement: AttitudeMeasurement,
        rows: NDArray[np.intp],
        noise: Array,
        counts: dict[str, float],
        offset_index: NDArray[np.intp] | None = None,
    ) -> None:
        self.node = node
        self.key = attitude_key(node)
        self.measurement = measurement
        self.offset_index = offset_index
        self.set_noise(noise)  # R over all the measurement's rows, fixed while optimising
        if offset_index is not None and self.noise_diagonal is None:
            raise InvalidObservationError(
                f"node {node}: offsets are modelled row by row and need independent rows"
            )
        self.counts = counts
        self.members = block_structure(measurement.blocks).members
        self.set_rows(rows)
        self.innovation = np.zeros(rows.size)
        self.jacobian = np.zeros((rows.size, 3))

    def set_noise(self, noise: Array) -> None:
        """Hold ``R`` over all rows: ``(m,)`` variances (SNRs, vectors), kept as such, or
        an ``(m, m)`` matrix (kept as its diagonal when it is diagonal), so that
        nothing later costs ``O(m^2)`` for independent rows."""
        noise = np.asarray(noise, dtype=float)
        if noise.ndim == 1:
            self.noise_diagonal: Array | None = noise
            self.noise: Array | None = None
            return
        d = np.diagonal(noise).copy()
        diagonal = np.count_nonzero(noise) == np.count_nonzero(d)
        self.noise_diagonal = d if diagonal else None
        self.noise = None if diagonal else noise

    def set_rows(self, rows: NDArray[np.intp]) -> None:
        """Use ``rows`` from now on (whitener, block labels)."""
        self.rows = rows
        labels = self.measurement.blocks[rows]
        blocks = block_structure(labels)
        self.block_ids, self.block_index = blocks.ids, blocks.index
        if self.noise_diagonal is not None:
            d = self.noise_diagonal[rows]
            if not (d > 0).all():  # also False for NaN
                raise InvalidObservationError(
                    f"node {self.node}: noise covariance not positive definite"
                )
            self.scale: Array | None = 1.0 / np.sqrt(d)
            self.cholesky: Array | None = None
            self.counts["n_used"] = float(self.block_ids.size)
            return
        r = self.noise[np.ix_(rows, rows)]
        self.scale = None
        try:
            if not np.all(np.isfinite(r)):
                raise np.linalg.LinAlgError
            self.cholesky = np.linalg.cholesky(r)
        except np.linalg.LinAlgError:
            raise InvalidObservationError(
                f"node {self.node}: noise covariance not positive definite"
            ) from None
        self.counts["n_used"] = float(self.block_ids.size)

    def whiten(self, x: Array) -> Array:
        """``W x`` for ``x`` with the used rows on its first axis."""
        if self.scale is not None:
            return x * self.scale.reshape(-1, *([1] * (x.ndim - 1)))
        return solve_triangular(self.cholesky, x, lower=True)

    def shifted(self, offsets: Array | None) -> AttitudeMeasurement:
        """The measurement with the pass's current ``offsets`` inside its model."""
        if self.offset_index is None or offsets is None:
            return self.measurement
        return self.measurement.with_offsets(offsets[self.offset_index])

    def evaluate(
        self, attitude: Rotation, offsets: Array | None = None
    ) -> tuple[Array, Array, NDArray[np.intp]]:
        """Innovation ``nu`` and ``-d nu / d delta`` (:func:`innovation_jacobian`) over the
        used rows at ``attitude``; the blocks that cannot be predicted there.

        With ``offsets`` (the pass's offset variables, when modelled) the
        Jacobian has a fourth column, ``-d nu / d o`` of each row's own offset
        (``dh / d o`` from :meth:`~AttitudeMeasurement.offset_slope`).
        """
        measurement = self.shifted(offsets)
        slope = None
        if self.offset_index is not None and offsets is not None:
            slope = measurement.offset_slope(attitude)
        return self.evaluated(measurement, measurement.predict(attitude), slope)

    def evaluated(
        self,
        measurement: AttitudeMeasurement,
        prediction: tuple[Array, Array],
        slope: Array | None = None,
    ) -> tuple[Array, Array, NDArray[np.intp]]:
        """:meth:`evaluate` from the (shifted) measurement's ``prediction`` at the attitude
        (``predict``'s values and Jacobians) and, with offsets, its ``offset_slope`` there."""
        predicted, jacobian = prediction
        with np.errstate(invalid="ignore"):
            nu = measurement.innovation(predicted[0])[self.rows]
        jac = innovation_jacobian(measurement, predicted[0], jacobian[0], self.members)
        jac = jac[self.rows]
        if slope is not None:
            jac = np.column_stack([jac, slope[self.rows]])
        bad = ~(np.isfinite(nu) & np.isfinite(jac).all(axis=1))
        if not bad.any():
            return nu, jac, NO_BLOCKS
        return nu, jac, np.unique(self.measurement.blocks[self.rows[bad]])

    def _kept(self, lost: NDArray[np.intp]) -> NDArray[np.bool_]:
        return ~np.isin(self.measurement.blocks[self.rows], lost)

    def block_norms(self, nu: Array, keep: NDArray[np.bool_] | None = None) -> Array:
        """Norms of the whitened residual per used block; blocks outside ``keep`` count 0.

        ``R`` is block-diagonal over the blocks (every implementation), so its
        Cholesky factor has no fill between blocks and zeroing the left-out
        rows leaves the others' whitened values unchanged.
        """
        if keep is not None:
            nu = np.where(keep, nu, 0.0)
        r = self.whiten(nu)
        return np.sqrt(np.bincount(self.block_index, r * r, self.block_ids.size))

    def cost(self, nu: Array, threshold: float | None, lost: NDArray[np.intp]) -> float:
        """Robust cost of the innovation ``nu`` over the used rows without the ``lost`` blocks."""
        keep = self._kept(lost) if lost.size else None
        return huber_cost(self.block_norms(nu, keep), threshold)

    def accept(self, nu: Array, jac: Array, lost: NDArray[np.intp]) -> None:
        """Make ``(nu, jac)`` the current linearisation, dropping the ``lost`` blocks."""
        if lost.size:
            keep = self._kept(lost)
            self.counts["n_unpredictable"] += float(lost.size)
            self.set_rows(self.rows[keep])
            nu, jac = nu[keep], jac[keep]
        self.innovation, self.jacobian = nu, jac

    def drop(self, lost: NDArray[np.intp]) -> None:
        """Drop the ``lost`` blocks from the current linearisation (counted unpredictable)."""
        if lost.size:
            self.accept(self.innovation, self.jacobian, lost)

    def current_cost(self, threshold: float | None, lost: NDArray[np.intp] | None = None) -> float:
        return self.cost(self.innovation, threshold, NO_BLOCKS if lost is None else lost)

    def weights(self, threshold: float | None) -> Array:
        """IRLS weight of each used block at the current linearisation."""
        return huber_weights(self.block_norms(self.innovation), threshold)

    def whitened_rows(self, threshold: float | None) -> tuple[Array, Array | None]:
        """``[A | b] = [-W K | W nu]`` ``(m, 4)`` over the used rows (IRLS-weighted), the
        linearisation ``|| A xi - b ||^2``, and with the offsets' column each row's
        coefficient ``+W (dh / d o)`` of its own offset (else ``None``)."""
        system = np.column_stack([-self.whiten(self.jacobian[:, :3]), self.whiten(self.innovation)])
        column = None if self.jacobian.shape[1] == 3 else self.whiten(self.jacobian[:, 3])
        if threshold is None:  # every weight 1
            return system, column
        root = np.sqrt(self.weights(threshold))[self.block_index]
        system *= root[:, None]
        return system, None if column is None else column * root

    def linear_factors(self, threshold: float | None) -> list[gtsam.JacobianFactor]:
        """:meth:`whitened_rows` as ``JacobianFactor`` s (:func:`linear_factors` of this
        factor alone); none once every block has been dropped."""
        return linear_factors([self], threshold)

    def whitened_system(self, nu: Array, jac: Array, lost: NDArray[np.intp]) -> tuple[Array, Array]:
        """``e = -W nu`` and ``de/dxi = -W K`` over the used rows from an :meth:`evaluate`
        result ``(nu, jac, lost)``, the rows of the ``lost`` blocks zero (finite where the
        model cannot predict): the nonlinear factor that GTSAM relinearises itself in
        :mod:`attopt.solvers.smoother.online` (no Huber weights, no compression)."""
        if lost.size:
            keep = self._kept(lost)
            nu, jac = np.where(keep, nu, 0.0), np.where(keep[:, None], jac, 0.0)
        return -self.whiten(nu), -self.whiten(jac)

    def normalised_residual(self) -> float:
        """``nu^T R^-1 nu`` over the used rows at the current linearisation (NaN if none)."""
        if self.rows.size == 0:
            return np.nan
        r = self.whiten(self.innovation)
        return float(r @ r)

    def n_downweighted(self, threshold: float | None) -> int:
        return int(np.count_nonzero(self.weights(threshold) < 1.0))


def linear_factors(
    factors: Sequence[EpochFactor], threshold: float | None
) -> list[gtsam.JacobianFactor]:
    """The ``JacobianFactor`` s of ``factors``' :meth:`~EpochFactor.whitened_rows`, in their
    order; none for a factor whose every block has been dropped.

    Without offsets: one factor on the epoch's attitude key, compressed by QR to at
    most three rows; the factors with as many rows are compressed together, one
    batched ``numpy.linalg.qr`` per row count (the same LAPACK routine on each matrix,
    so the same factors as one call each, in a twentieth of the time over a pass).
    With offsets: one single-row factor per used row on the attitude key and the row's
    offset key (the reference the smoother's own elimination,
    :mod:`attopt.solvers.smoother.offset_elimination`, is tested against); rows cannot
    be compressed without coupling every offset seen at the epoch.
    """
    out: list[gtsam.JacobianFactor | None] = []
    compress: dict[int, list[tuple[int, int, Array]]] = {}  # rows -> (slot, key, system)
    for f in factors:
        if f.rows.size == 0:
            continue
        system, column = f.whitened_rows(threshold)
        if column is not None:
            keys = [offset_key(j) for j in f.offset_index[f.rows]]
            out += [
                gtsam.JacobianFactor(f.key, row[None, :3], key, np.array([[c]]), row[3:], UNIT1)
                for row, key, c in zip(system, keys, column, strict=True)
            ]
        elif system.shape[0] > 3:
            compress.setdefault(system.shape[0], []).append((len(out), f.key, system))
            out.append(None)
        else:
            out.append(_attitude_factor(f.key, system))
    for group in compress.values():
        triangles = np.linalg.qr(np.stack([system for *_, system in group]), mode="r")
        for (slot, key, _), triangle in zip(group, triangles, strict=True):
            out[slot] = _attitude_factor(key, triangle[:3])
    return out  # every slot filled


def _attitude_factor(key: int, system: Array) -> gtsam.JacobianFactor:
    """``|| A xi - b ||^2`` of ``system = [A | b]`` on the attitude ``key``."""
    m = system.shape[0]
    return gtsam.JacobianFactor(key, system[:, :3], system[:, 3], gtsam.noiseModel.Unit.Create(m))


def evaluate_factors(
    factors: Sequence[EpochFactor], attitudes: Rotation, offsets: Array | None = None
) -> list[tuple[Array, Array, NDArray[np.intp]]]:
    """:meth:`EpochFactor.evaluate` of every factor at its node's attitude in ``attitudes``
    (all nodes), the measurements predicted together
    (:func:`~attopt.formulations.attitude_measurement.predict_each`), and so are the offsets'
    slopes (:func:`~attopt.formulations.attitude_measurement.offset_slope_each`)."""
    measurements = [f.shifted(offsets) for f in factors]
    nodes = np.array([f.node for f in factors], dtype=np.intp)
    predictions = predict_each(measurements, attitudes[nodes])
    slopes: list[Array | None] = [None] * len(factors)
    if offsets is not None:
        with_offsets = [i for i, f in enumerate(factors) if f.offset_index is not None]
        each = offset_slope_each(
            [measurements[i] for i in with_offsets], attitudes[nodes[with_offsets]]
        )
        for i, slope in zip(with_offsets, each, strict=True):
            slopes[i] = slope
    return [
        f.evaluated(measurement, prediction, slope)
        for f, measurement, prediction, slope in zip(
            factors, measurements, predictions, slopes, strict=True
        )
    ]


def prepare_factor(
    node: int,
    measurement: AttitudeMeasurement,
    attitude: Rotation | None,
    attitude_covariance: Array,
    gate_probability: float,
    offset_index: NDArray[np.intp] | None = None,
    offset_variance: float = 0.0,
    prediction: tuple[Array, Array] | None = None,
    noise: Array | None = None,
) -> tuple[EpochFactor | None, dict[str, float]]:
    """The epoch's factor at the initial estimate (rows, ``R``, gating; module docstring).

    ``prediction`` and ``noise``: the measurement's ``predict`` and ``noise_covariance_at``
    at ``attitude`` when already computed (over a pass by
    :func:`~attopt.formulations.attitude_measurement.predict_each` and
    :func:`~attopt.formulations.attitude_measurement.noise_covariance_each`); with both
    given, ``attitude`` is not used and may be ``None``.

    With offsets modelled (``offset_index``, all offsets 0 initially) the gate
    adds the offsets' prior variance to ``R``, so that a transmitter's offset
    is not rejected as an outlier.  Returns ``None`` (with the counts) when no
    row is left.
    """
    counts = dict.fromkeys(COUNTS, 0.0)
    if measurement.size == 0:
        return None, counts
    predicted, jacobian = measurement.predict(attitude) if prediction is None else prediction
    with np.errstate(invalid="ignore"):
        innovation = measurement.innovation(predicted[0])
    keep, n_nan, n_unpredictable = usable_rows(measurement, predicted, innovation[None])
    counts["n_nan"], counts["n_unpredictable"] = float(n_nan), float(n_unpredictable)
    rows = np.flatnonzero(keep)
    if rows.size == 0:
        return None, counts
    if noise is None:
        noise = measurement.noise_covariance_at(attitude)
    noise = np.asarray(noise, dtype=float)
    factor = EpochFactor(node, measurement, rows, noise, counts, offset_index)
    nu = innovation[rows]
    h = jacobian[0][rows]
    gate_noise = noise_subset(noise, rows)
    if offset_variance:
        gate_noise = gate_noise + offset_variance * (
            1.0 if gate_noise.ndim == 1 else np.eye(rows.size)
        )
    accepted = gate(
        nu,
        h.T,
        attitude_covariance,
        gate_noise,
        measurement.blocks[rows],
        gate_probability,
    )
    if not accepted.all():
        counts["n_gated"] = float(count_blocks(measurement.blocks[rows[~accepted]]))
        rows = rows[accepted]
        if rows.size == 0:
            return None, counts
        factor.set_rows(rows)
    with np.errstate(invalid="ignore"):
        full = innovation_jacobian(measurement, predicted[0], jacobian[0], factor.members)
    factor.accept(nu[accepted], full[rows], NO_BLOCKS)
    return factor, counts
