"""Multiplicative extended Kalman filter with gyro bias (Liu et al. 2023 secs. 4.2-4.5).

Lefferts, Markley and Shuster (1982); Markley and Crassidis (2014), ch. 6.
Error state ``x = [delta, delta_beta]`` (:mod:`attopt.solvers.filters.common`).

Propagation over each step ``dt`` of the gyro timeline (the record cut at the
epochs, :mod:`attopt.solvers.gyro_timeline`) with the estimated rate
``w = omega_measured - beta_hat`` (Liu et al. 2023 eqs. 33-36): the attitude by
``exp(-[w x] dt)`` and the covariance by ``P <- Phi P Phi^T + Q`` with the
closed-form :func:`~attopt.formulations.gyro.error_state_transition` and
:meth:`~attopt.formulations.gyro.GyroModel.process_noise` (Markley and Crassidis eq.
6.93, instead of the paper's truncated series of eq. 47 and ``Q_k = Q``).

Update at an epoch with a measurement: ``H = [dh/d delta, 0]`` from the
measurement's own (AD) Jacobian, ``K = P H^T S^-1``, ``S = H P H^T + R``
(iterated after a large correction, :func:`update`), the
Joseph form ``P <- (I - K H) P (I - K H)^T + K R K^T`` (instead of the paper's
eq. 56), then the reset: the attitude is corrected by ``delta`` (eq. 61),
the bias by ``delta_beta`` (eq. 59), and the error state returns to zero
(eq. 62).  All blocks of an epoch are processed in one update after gating.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.gyro import GyroModel
from attopt.solvers.blocks import count_blocks
from attopt.solvers.filters.common import (
    STATE_SIZE,
    Array,
    FilterOptions,
    GyroStateFilter,
    PreparedGyro,
    apply_error,
    error_jacobian,
    gate,
    huber_noise,
    kalman_gain,
    linearised,
    noise_sandwich,
    noise_subset,
    propagate_attitude,
    propagate_covariance,
    repair_covariance,
    solve_noise,
    usable_rows,
)
from attopt.solvers.filters.offsets import RowOffsets, shifted
from attopt.solvers.filters.vector_update import compiled_update
from attopt.solvers.sequential import OFFSET_DIAGNOSTICS


def propagate(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    gyro: PreparedGyro,
    steps: slice,
    model: GyroModel,
) -> tuple[Rotation, Array, Array]:
    """Attitude, covariance and the transition ``Phi`` over gyro steps ``steps``."""
    rates = gyro.rates[steps] - bias
    dt = gyro.dt[steps]
    covariance, total = propagate_covariance(
        covariance, rates, gyro.hold_variance[steps], model, dt
    )
    return propagate_attitude(attitude, rates, dt), covariance, total


MAX_HALVINGS = 8
"""Backtracking halvings of a Gauss-Newton step that raised the MAP cost."""


def update(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    measurement: AttitudeMeasurement,
    options: FilterOptions,
    offsets: RowOffsets | None = None,
) -> tuple[Rotation, Array, Array, dict[str, float], Array]:
    """One iterated measurement update with gating, Joseph form and reset.

    Gating, and the Huber weights when ``options.huber_threshold`` is set
    (:func:`~attopt.solvers.filters.common.huber_noise`), use the prediction at the prior
    estimate.  The update is the
    iterated EKF's Gauss-Newton step on the MAP cost (Bell and Cathey 1993):
    ``x_{i+1} = K_i (z - h(x_i) + H_i x_i)`` with ``h`` and ``H_i``
    re-evaluated at ``x_i``; ``H_i`` is the measurement's body-frame Jacobian
    times :func:`~attopt.solvers.filters.common.error_jacobian` ``(x_i)``, the
    derivative with respect to the state, so the iteration converges
    quadratically.  It is repeated while the step's second-order term
    ``|s|^2 / 2`` exceeds ``options.relinearise_fraction`` of the smallest
    posterior attitude standard deviation: one pass (the plain EKF update) in
    steady state; several after a large initial error against precise
    measurements, where one linear step would leave an error far larger than
    the posterior covariance admits (later innovations would then be gated).
    Each Gauss-Newton step is checked on the MAP cost ``(1/2) nu^T R^-1 nu +
    (1/2) x^T P^-1 x`` at the next linearisation: a step that raises it is
    halved (at most :data:`MAX_HALVINGS` times, then the last accepted point
    is kept), so an iteration never ends at a point worse than where it
    started.  The counts' ``nis`` is ``nu~^T S^-1 nu~`` with ``nu~ = z - h(x_i) +
    H_i x_i``, the innovation relinearised at the last iterate (twice the MAP cost at
    its optimum, to Gauss-Newton accuracy: chi-square with ``nis_dof`` rows for a
    consistent filter, and not inflated by the first linearisation's error after a
    large correction), summed over a window by the consistency test
    (:func:`~attopt.solvers.sequential.inconsistent_epochs`).  It does not protect against a
    second basin of the cost: from a prior far off (a 2.5-sigma draw of the
    experiments' 10 deg) the first update of an ``adsb-snr`` pass can converge to
    a local minimum 50 deg away (measured in 1 of 100 trials; docs/filters.md).
    The covariance of the error relative to ``A^-`` is finally carried to the
    body frame of the reset attitude, ``P <- T P T^T`` with ``T =
    blockdiag(J(x), I)``.

    With ``offsets`` (:mod:`attopt.solvers.filters.offsets`) ``covariance`` is the
    joint one of ``[delta, delta_beta, delta_o]``, each row is predicted with its
    offset ``o + delta_o`` in its model (:func:`~attopt.solvers.filters.offsets.shifted`)
    and ``H`` gains the rows' ``dh / d o`` in their offsets' columns; the last item
    returned is the offsets' increment ``delta_o`` (empty without).

    Unit vectors without offsets run as one compiled call
    (:func:`attopt.solvers.filters.vector_update.compiled_update`); everything else, and
    every measurement under ``ATTOPT_KERNELS=interpreted``, runs the numpy path,
    :func:`update_reference`, which is also the compiled call's reference.
    """
    if offsets is None:
        compiled = compiled_update(attitude, bias, covariance, measurement, options, MAX_HALVINGS)
        if compiled is not None:
            return compiled
    return update_reference(attitude, bias, covariance, measurement, options, offsets)


def update_reference(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    measurement: AttitudeMeasurement,
    options: FilterOptions,
    offsets: RowOffsets | None = None,
) -> tuple[Rotation, Array, Array, dict[str, float], Array]:
    """:func:`update`'s numpy path: any measurement, with or without offsets and the Huber
    weights (the algorithm is :func:`update`'s docstring)."""
    n_state = covariance.shape[0]
    eye = np.eye(n_state)
    blocks = measurement.blocks
    state = np.zeros(n_state)
    r_all = shifted(measurement, offsets, state[STATE_SIZE:]).noise_covariance_at(attitude)
    counts = {"n_gated": 0.0, "n_nan": 0.0, "n_unpredictable": 0.0, "nis": np.nan, "nis_dof": 0.0}
    counts |= {"n_used": 0.0, "covariance_repairs": 0.0, "update_iterations": 0.0}
    counts["n_downweighted"] = 0.0
    current = attitude
    prior_information = np.linalg.inv(covariance)
    accepted_state, accepted_cost, trial_step, halvings = state, np.inf, state, 0
    for iteration in range(options.max_update_iterations):
        predicting = shifted(measurement, offsets, state[STATE_SIZE:])
        predicted, jacobian = predicting.predict(current)
        with np.errstate(invalid="ignore"):
            innovation = predicting.innovation(predicted[0])
        h_all = np.zeros((measurement.size, n_state))
        h_all[:, :3] = jacobian[0] if iteration == 0 else jacobian[0] @ error_jacobian(state[:3])
        if offsets is not None:
            h_all[:, STATE_SIZE:] = offsets.slopes(predicting, current)
        counts["update_iterations"] = float(iteration + 1)
        if iteration == 0:
            keep, n_nan, n_unpredictable = usable_rows(measurement, predicted, innovation[None])
            rows = np.flatnonzero(keep)
            accepted = gate(
                innovation[rows],
                h_all[rows].T,
                covariance,
                noise_subset(r_all, rows),
                blocks[rows],
                options.gate_probability,
            )
            counts["n_gated"] = float(count_blocks(blocks[rows[~accepted]]))
            counts["n_nan"], counts["n_unpredictable"] = float(n_nan), float(n_unpredictable)
            rows = rows[accepted]
            if rows.size == 0:
                return attitude, bias, covariance, counts, state[STATE_SIZE:]
            r_all = huber_noise(
                r_all,
                rows,
                innovation[rows],
                h_all[rows].T,
                covariance,
                blocks[rows],
                options,
                counts,
            )
            r = noise_subset(r_all, rows)
        else:  # relinearised: drop blocks the model can no longer predict
            lost = np.unique(blocks[rows[~np.isfinite(innovation[rows])]])
            if lost.size:
                rows = rows[~np.isin(blocks[rows], lost)]
                counts["n_unpredictable"] += float(lost.size)
                accepted_cost = np.inf  # another sum: costs are not comparable
                if rows.size == 0:
                    break
                r = noise_subset(r_all, rows)
        nu = innovation[rows]
        cost = 0.5 * (nu @ solve_noise(r, nu) + state @ prior_information @ state)
        if not cost <= accepted_cost:  # backtrack: halve the last step
            if halvings == MAX_HALVINGS or not np.isfinite(accepted_cost):
                state = accepted_state  # keep the last accepted point (gain, h are its)
                break
            halvings += 1
            trial_step = 0.5 * trial_step
            state = accepted_state + trial_step
            current = apply_error(state[:3], attitude)
            continue
        accepted_state, accepted_cost, halvings = state, cost, 0
        h = h_all[rows]
        relinearised = nu + h @ state  # the innovation relinearised at the iterate
        gain, nis, posterior = kalman_gain(covariance, h, r, relinearised, prior_information)
        trial_step = gain @ relinearised - state
        state = state + trial_step
        counts["nis"], counts["nis_dof"] = nis, float(rows.size)
        if not np.isfinite(state).all():  # flagged by the caller
            return attitude, np.full(3, np.nan), covariance, counts, state[STATE_SIZE:]
        if linearised(trial_step, posterior, options.relinearise_fraction):
            break
        current = apply_error(state[:3], attitude)
    joseph = eye - gain @ h
    covariance = joseph @ covariance @ joseph.T + noise_sandwich(gain, r)
    reset = np.eye(n_state)
    reset[:3, :3] = error_jacobian(state[:3])
    covariance, repaired = repair_covariance(reset @ covariance @ reset.T)
    counts["n_used"] = float(count_blocks(blocks[rows]))
    counts["covariance_repairs"] = float(repaired)
    attitude = apply_error(state[:3], attitude)
    return attitude, bias + state[3:STATE_SIZE], covariance, counts, state[STATE_SIZE:]


class MekfFilter(GyroStateFilter):
    """The MEKF's state and steps (module docstring), for
    :func:`attopt.solvers.sequential.run_filter`.

    Starts at the first gyro sample with ``prior`` (``[attitude, bias]``);
    :meth:`predict` propagates over the gyro steps to a sample time or an
    epoch of the timeline, :meth:`update` is :func:`update`.
    """

    smoothable = True

    def predict(self, t: float) -> dict[str, float]:
        stop = self.gyro.node(t)
        self.attitude, self.covariance, self.transition = propagate(
            self.attitude, self.bias, self.covariance, self.gyro, slice(self.node, stop), self.model
        )
        self.advance(self.transition, stop)
        return {"gyro_gap_s": self.gyro.gap_at(stop)}

    def update(self, measurement: AttitudeMeasurement | None) -> dict[str, float] | None:
        if measurement is None:
            return None
        covariance, rows = self.joint(measurement)
        self.attitude, self.bias, covariance, counts, increment = update(
            self.attitude, self.bias, covariance, measurement, self.options, rows
        )
        return counts | self.absorb(covariance, increment)


class MekfOffsetFilter(MekfFilter):
    """:class:`MekfFilter` with transmitter offsets (:mod:`attopt.solvers.filters.offsets`):
    not smoothable, since the RTS pass does not carry the offsets; it counts their test
    against the prior."""

    smoothable = False
    diagnostics = OFFSET_DIAGNOSTICS
