"""USQUE, the unscented quaternion estimator with gyro bias (Pimienta-Penalver and
Crassidis sec. V.B).

Crassidis and Markley (2003), "Unscented filtering for spacecraft attitude
estimation", JGCD 26(4) 536-542 ("CM"; its text is not among the project's
sources, so the equations below are numbered (U1)-(U9) here rather than by
CM's numbering).  Pimienta-Penalver and Crassidis sec. V.B runs this filter on SNR measurements
with the multiplicative body-frame error of its eq. 26.  Same inputs,
outputs, diagnostics and fault handling as the MEKF
(:mod:`attopt.solvers.filters.mekf`; both run by
:func:`attopt.solvers.sequential.run_filter`) and the same measurement
interface, of which only the predicted values are used: no Jacobian is
evaluated.

State and sigma points.  The filter carries the attitude estimate ``A``
(reference -> body), the bias ``beta`` and the ``6 x 6`` covariance ``P`` of
the error state ``x = [delta, delta_beta]``, ``delta`` the generalised
Rodrigues parameters of ``A_true A^T`` with ``a = 1, f = 4``, CM's choice
(:func:`~attopt.solvers.filters.common.error_vector`,
:func:`~attopt.solvers.filters.common.apply_error`).  At the start of every
propagation and update the error mean is zero (it has been folded into ``A``
and ``beta``), and the ``2 n + 1 = 13`` sigma points are::

    chi_0 = 0,   chi_{+j}, chi_{-j} = +/- L_j,   L L^T = (n + lambda) P,      (U1)
    w_0 = lambda / (n + lambda),   w_{+/-j} = 1 / (2 (n + lambda)),           (U2)

``L_j`` the columns of the Cholesky factor, ``n = 6``, and the scaled
unscented transform (Julier 2002; Wan and van der Merwe 2000): ``lambda =
alpha^2 n - n`` with ``alpha = 0.5`` (points at ``1.22 sigma``), and for
covariances ``w_0 + 1 - alpha^2 + beta``, ``beta = 2`` (see the deviations
below: CM's ``lambda = 1`` is ``alpha = sqrt(7/6), beta = 0``).

Propagation from one output epoch to the next, over all the gyro steps
between them at once and vectorised over the sigma points: sigma point ``i``
is the attitude ``A_i = apply_error(chi_i[:3], A)`` with bias ``beta_i =
beta + chi_i[3:]``, carried through the exact kinematics with its own rates
``omega_measured - beta_i`` (:func:`~attopt.solvers.filters.common.propagate_quaternion`).
The propagated reference is sigma point 0's attitude ``A_0'``; the
propagated points are ``chi_i' = [error_vector(A_i', A_0'), chi_i[3:]]``
(the bias is a random walk: its points do not move), and::

    x^- = sum_i w_i chi_i',                                                    (U3)
    P^- = T(x^-) [sum_i w_i (chi_i' - x^-)(chi_i' - x^-)^T + Q_interval] T(x^-)^T,   (U4)
    A^- = apply_error(x^-[:3], A_0'),   beta^- = beta + x^-[3:].              (U5)

(U5) folds the mean into the estimate, and ``T(x) = blockdiag(J(x[:3]), I)``
in (U4) carries the covariance of the error about ``A_0'`` to the error
about ``A^-`` to first order (``J`` of :func:`~attopt.solvers.filters.common.error_jacobian`,
the MEKF's reset; :func:`carried`).

Update at an epoch with a measurement: fresh sigma points (U1) from ``P^-``
about ``A^-``, ``A_i = apply_error(chi_i[:3], A^-)``, are predicted in one
call, ``h_i = h(A_i)`` (the model's values only, ``jacobian=False``), and
``R`` is the measurement's noise covariance at ``A^-`` (attitude-dependent
for the truncated SNR model, evaluated where the MEKF evaluates it); rows
that are NaN for any sigma point or in ``z`` are left out (whole blocks,
:func:`~attopt.solvers.filters.common.usable_rows`).  With
the measurement's own innovation ``d_i = z - h_i`` (wrapped angles,
geodesic unit-vector differences)::

    nu = sum_i w_i d_i,                                                        (U6)
    P_nunu = sum_i w_i (nu - d_i)(nu - d_i)^T + R,   P_xnu = sum_i w_i chi_i (nu - d_i)^T,   (U7)
    K = P_xnu P_nunu^-1,   x^+ = K nu,   P^+ = P^- - K P_nunu K^T,             (U8)
    A^+ = apply_error(x^+[:3], A^-),  beta^+ = beta^- + x^+[3:],  P^+ <- T(x^+) P^+ T(x^+)^T, (U9)

``nu - d_i`` standing for ``h_i - h_mean`` (exact for ``d = z - h``, to
first order for nonlinear ones such as the unit vectors').  Each block is first gated on
``nu`` and its diagonal block of ``P_nunu`` (:func:`~attopt.solvers.filters.common.gate`);
(U8) uses the accepted rows; ``P^+`` is floored if it loses definiteness
(:func:`~attopt.solvers.filters.common.repair_covariance`).  ``nis`` is ``nu^T
P_nunu^-1 nu`` over the accepted rows, with ``nu`` relinearised at the last iterate
(``nu + H dx``: the Gauss-Newton value of twice the update's cost at its optimum, robust
to a large first innovation; ``nis_dof`` its rows), which the consistency test of
:func:`~attopt.solvers.sequential.inconsistent_epochs` sums over a window.

Deviations from CM:

* *Information form.*  (U7)-(U8) are evaluated as ``P_xnu P_nunu^-1`` through
  the statistical linearisation ``P_nunu = H P H^T + Omega + R``, ``P_xnu =
  P H^T`` (:func:`regression`) and the information-form gain
  (:func:`~attopt.solvers.filters.common.kalman_gain`), keeping only the diagonal of
  the linearisation residual ``Omega``: the residuals of different
  observations are treated as independent.  The cost is then linear in the
  number of observations (an ``adsb-snr`` epoch can hold 2,000 SNRs, whose
  full ``P_nunu`` would take seconds to factor) instead of cubic.

* *Sigma-point spread.*  CM's ``lambda = 1`` places the points at ``2.65
  sigma``.  With the experiments' 10 deg initial attitude sigma that is 26
  deg: SNR observations leave the antenna's main lobe at some points (they
  are then dropped) and the regression over such a spread averages the SNR
  response away, so the update hardly informs the worst-known axis and the
  filter does not converge (measured on ``adsb-snr`` with the ``liu2023``
  gyro: the pitch sigma stayed at 7.7 deg for more than ten epochs while the
  MEKF's fell to 0.6 deg, and the errors reached 90 deg).  With ``alpha =
  0.5`` (1.22 sigma) the same run converges like the MEKF (RMS within 2 %).

* *Additive process noise.*  CM draw the sigma points from ``P + Q_bar`` and
  add ``Q_bar`` again after propagation.  Here they come from ``P`` alone
  and the noise is added once, after propagation (U4): the standard UKF for
  additive noise, which does not count the noise twice.
* *Interval noise.*  ``Q_interval`` accumulates the steps' noise over the
  interval, ``Q <- Phi_j Q Phi_j^T + Q_j`` from ``Q = 0``, ``Q_j`` the
  per-step :meth:`~attopt.formulations.gyro.GyroModel.process_noise` plus the
  gyro-gap growth (:func:`~attopt.solvers.filters.common.step_noise`) and ``Phi_j``
  the closed-form :func:`~attopt.formulations.gyro.error_state_transition` at the
  mean rate ``omega_measured - beta`` (:func:`unscented_prediction`): the noise
  part of the MEKF's covariance propagation.  Drawing fresh sigma points at
  every gyro step instead (CM propagate one gyro step per filter step)
  changed the estimates by less than 1e-6 of the filter sigma at 10 Hz over
  1 s intervals, with both a MEMS-class and Liu et al. 2023's gyro, and took four
  times as long.
* *Fresh sigma points at the update* (CM reuse the propagated ones), centred
  on the folded estimate so that their mean error is zero; ``Q_interval`` is
  then represented in them.
* *Iterated update after a large correction.*  One pass of (U6)-(U9) from a
  20 deg error against 0.001 rad vectors leaves a 5 deg error with a 0.1-0.2
  deg posterior sigma (later measurements are then gated and the filter is
  lost), as one EKF pass does.  The MEKF iterates its update for this; USQUE
  does the same with the iterated posterior linearisation filter
  (:func:`update`): while the attitude step's second-order term exceeds
  ``options.relinearise_fraction`` of the posterior attitude sigma (the
  MEKF's test, :func:`~attopt.solvers.filters.common.linearised`; at most
  ``options.max_update_iterations`` passes), sigma points drawn from the
  current posterior re-linearise the measurement statistically.  The first
  pass is exactly (U6)-(U9); ``update_iterations`` counts the passes (1 in
  steady state).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.gyro import GyroModel
from attopt.formulations.kernels import compiled_loops
from attopt.solvers.blocks import count_blocks
from attopt.solvers.filters import compiled
from attopt.solvers.filters.common import (
    STATE_SIZE,
    Array,
    FilterOptions,
    GyroStateFilter,
    PreparedGyro,
    apply_error,
    covariance_steps,
    error_jacobian,
    gate,
    huber_noise,
    kalman_gain,
    linearised,
    noise_subset,
    perturb_quaternion,
    quaternion_error_vector,
    quaternion_steps,
    repair_covariance,
    step_noise,
    usable_rows,
)
from attopt.solvers.filters.offsets import RowOffsets, shifted
from attopt.solvers.filters.vector_unscented_update import compiled_update
from attopt.solvers.sequential import OFFSET_DIAGNOSTICS

ALPHA = 0.5
"""Spread of the scaled unscented transform (module docstring: not CM's ``lambda = 1``)."""
BETA = 2.0
"""Prior-distribution weight of the scaled transform (2: Gaussian)."""
LAMBDA = ALPHA**2 * STATE_SIZE - STATE_SIZE
WEIGHTS = np.full(2 * STATE_SIZE + 1, 0.5 / (STATE_SIZE + LAMBDA))
WEIGHTS[0] = LAMBDA / (STATE_SIZE + LAMBDA)
COVARIANCE_WEIGHTS = WEIGHTS.copy()
COVARIANCE_WEIGHTS[0] += 1.0 - ALPHA**2 + BETA


def finite(*arrays: Array) -> bool:
    """Whether every entry of ``arrays`` is finite."""
    return all(np.isfinite(a).all() for a in arrays)


def sigma_offsets(covariance: Array) -> tuple[Array, bool]:
    """``(13, 6)`` offsets ``0, +L_i, -L_i`` of the sigma points, ``L L^T = (n + lambda) P``;
    whether ``P`` had to be repaired first."""
    try:
        root = np.linalg.cholesky((STATE_SIZE + LAMBDA) * covariance)
        repaired = False
    except np.linalg.LinAlgError:
        covariance, repaired = repair_covariance(covariance)
        root = np.linalg.cholesky((STATE_SIZE + LAMBDA) * covariance)
    return np.concatenate([np.zeros((1, STATE_SIZE)), root.T, -root.T]), repaired


def carry(state: Array, size: int = STATE_SIZE) -> Array:
    """``T = blockdiag(J, I)`` (``size x size``): it carries an error about ``A`` to the
    error about ``apply_error(state[:3], A)`` to first order, ``J`` of
    :func:`~attopt.solvers.filters.common.error_jacobian` (the MEKF's reset)."""
    reset = np.eye(size)
    reset[:3, :3] = error_jacobian(state[:3])
    return reset


def carried(covariance: Array, state: Array) -> Array:
    """The covariance of the error about ``apply_error(state[:3], A)`` from that about
    ``A``: ``T P T^T`` (:func:`carry`)."""
    reset = carry(state, covariance.shape[0])
    return reset @ covariance @ reset.T


def propagate(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    gyro: PreparedGyro,
    steps: slice,
    model: GyroModel,
    regress: bool = True,
) -> tuple[Rotation, Array, Array, Array | None, bool]:
    """Unscented prediction (U1)-(U5) over gyro steps ``steps``, mean folded in
    (:func:`unscented_prediction`, or its compiled loop), and its statistical transition
    ``T(x^-) Phi``, ``Phi = P_{x'x} P^-1`` the regression of the propagated sigma points
    on the drawn ones (:func:`regression`; what carries the offsets' cross-covariance,
    :mod:`attopt.solvers.filters.offsets`; ``None`` unless ``regress``, nothing else
    needing it); the last item says whether the covariance was repaired to draw the
    sigma points."""
    rates, dt = gyro.rates[steps], gyro.dt[steps]
    if rates.shape[0] == 0:
        return attitude, bias, covariance, np.eye(STATE_SIZE), False
    offsets, repaired = sigma_offsets(covariance)
    noise = step_noise(model, dt, gyro.hold_variance[steps])
    prediction = compiled.unscented_prediction if compiled_loops() else unscented_prediction
    quaternion, mean, covariance, spread = prediction(
        offsets, attitude.as_quat(), bias, rates, dt, noise
    )
    transition = carry(mean) @ regression(spread, offsets)[0] if regress else None
    return Rotation.from_quat(quaternion), bias + mean[3:], covariance, transition, repaired


def unscented_prediction(
    offsets: Array, quaternion: Array, bias: Array, rates: Array, dt: Array, noise: Array
) -> tuple[Array, Array, Array, Array]:
    """(U1)-(U5) from the sigma points' ``offsets`` (:func:`sigma_offsets`) about the
    attitude ``quaternion`` and ``bias``, over gyro steps at ``rates`` with lengths ``dt``
    and noises ``noise`` (:func:`~attopt.solvers.filters.common.step_noise`): the
    propagated attitude's quaternion (mean folded in), the mean error state, the
    covariance about the propagated attitude, and the points' deviations from their
    mean.

    The interval noise (U4) is the steps' noise accumulated from zero at the mean rate
    ``rates - bias`` (module docstring).  The numpy reference of
    :func:`attopt.solvers.filters.compiled.unscented_prediction`.
    """
    sigma_rates = rates[None] - (bias + offsets[:, 3:])[:, None]
    sigma_attitudes = perturb_quaternion(offsets[:, :3], quaternion)  # (U1)
    propagated = quaternion_steps(sigma_attitudes, sigma_rates, dt)  # (U2)
    errors = quaternion_error_vector(propagated, propagated[0])
    points = np.concatenate([errors, offsets[:, 3:]], axis=1)
    mean = WEIGHTS @ points  # (U3)
    spread = points - mean
    zero = np.zeros((STATE_SIZE, STATE_SIZE))
    interval = covariance_steps(zero, rates - bias, dt, noise)[0]
    covariance = carried((COVARIANCE_WEIGHTS * spread.T) @ spread + interval, mean)  # (U4)
    return perturb_quaternion(mean[:3], propagated[0]), mean, covariance, spread  # (U5)


def regression(deviation: Array, offsets: Array) -> tuple[Array, Array]:
    """Statistical linear regression of ``h`` on the error state over sigma points.

    ``deviation`` ``(13, r)`` holds ``h_i - h_mean`` and ``offsets`` the sigma
    points' offsets from their centre (columns of ``L``, ``L L^T = (n +
    lambda) P``).  Returns ``H`` (``r x 6``) with ``H = P_xh^T P^-1 = (1/2) D
    L^-1``, ``D`` the central differences ``h_{+j} - h_{-j}``, and the
    variances of the regression residual, the diagonal of ``Omega = P_hh - H
    P H^T``, ``H P H^T = D D^T / (4 (n + lambda))`` (module docstring: the
    off-diagonal terms are dropped).
    """
    n = STATE_SIZE
    differences = deviation[1 : n + 1] - deviation[n + 1 :]
    h = 0.5 * np.linalg.solve(offsets[1 : n + 1], differences).T  # rows of offsets: L^T
    spread = COVARIANCE_WEIGHTS @ deviation**2
    return h, spread - np.sum(differences**2, axis=0) / (4.0 * (n + LAMBDA))


def update(
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    measurement: AttitudeMeasurement,
    options: FilterOptions,
    offsets: RowOffsets | None = None,
) -> tuple[Rotation, Array, Array, dict[str, float], Array]:
    """Unscented measurement update (U6)-(U9) with gating.

    The first pass is the plain unscented update.  While the attitude step is
    not :func:`~attopt.solvers.filters.common.linearised` (at most
    ``options.max_update_iterations`` passes) it is repeated as the iterated
    posterior linearisation filter (Garcia-Fernandez, Svensson, Morelande
    and Sarkka 2015, IEEE Trans. Signal Process. 63(20)): sigma
    points drawn from the current posterior ``(x_i, P_i)`` give the
    regression ``h ~ H x + b`` with residual covariance ``Omega``
    (:func:`regression`), and the linear update of the prior ``(0, P^-)``
    with it is ``S = H P^- H^T + Omega + R``, ``K = P^- H^T S^-1``,
    ``x_{i+1} = K (nu_i + H x_i)``, ``P_{i+1} = P^- - K S K^T``, ``nu_i``
    the sigma-weighted innovation at ``x_i``.  With ``x_0 = 0`` and ``P_0 =
    P^-`` this is the unscented update itself (``H P^- H^T + Omega = P_nunu
    - R``, ``P^- H^T = P_xnu``).  Gating, and the Huber weights when
    ``options.huber_threshold`` is set (:func:`~attopt.solvers.filters.common.huber_noise`),
    use the first pass.

    With ``offsets`` (:mod:`attopt.solvers.filters.offsets`) ``covariance`` is the
    joint one of ``[delta, delta_beta, delta_o]``.  The sigma points are drawn over
    ``[delta, delta_beta]`` alone, each row predicted with its offset ``o + delta_o``
    inside its model, and the offsets enter linearised: ``H`` gains the rows'
    ``dh / d o`` in their offsets' columns (at the centre point; 1 for the Gaussian
    SNR model, so that the unscented transform over the joint state, whose
    Cholesky factor's offset columns move only the offsets, is this one exactly),
    and the first pass's innovation covariance adds the offsets' terms
    (:func:`with_offsets`).  The last item returned is the offsets' increment
    ``delta_o`` (empty without).

    Unit vectors without offsets run as one compiled call
    (:func:`attopt.solvers.filters.vector_unscented_update.compiled_update`); everything
    else, and every measurement under ``ATTOPT_KERNELS=interpreted``, runs the numpy
    path, :func:`update_reference`, which is also the compiled call's reference.
    """
    if offsets is None:
        weights = (WEIGHTS, COVARIANCE_WEIGHTS, LAMBDA)
        compiled = compiled_update(attitude, bias, covariance, measurement, options, weights)
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
    counts = {"n_gated": 0.0, "n_nan": 0.0, "n_unpredictable": 0.0, "nis": np.nan, "nis_dof": 0.0}
    counts |= {"n_used": 0.0, "covariance_repairs": 0.0, "update_iterations": 0.0}
    counts["n_downweighted"] = 0.0
    n_state = covariance.shape[0]
    state = np.zeros(n_state)
    sigma, repaired = sigma_offsets(covariance[:STATE_SIZE, :STATE_SIZE])
    counts["covariance_repairs"] = float(repaired)
    predicting = shifted(measurement, offsets, state[STATE_SIZE:])
    predicted, _ = predicting.predict(apply_error(sigma[:, :3], attitude), jacobian=False)
    with np.errstate(invalid="ignore"):  # rows left out may hold NaN
        innovations = predicting.innovation(predicted)
    keep, n_nan, n_unpredictable = usable_rows(measurement, predicted, innovations)
    counts["n_nan"], counts["n_unpredictable"] = float(n_nan), float(n_unpredictable)
    rows = np.flatnonzero(keep)
    if rows.size == 0:
        return attitude, bias, covariance, counts, state[STATE_SIZE:]
    blocks = measurement.blocks[rows]
    innovations = innovations[:, rows]
    slopes = None if offsets is None else offsets.slopes(predicting, attitude)[rows]
    nu = WEIGHTS @ innovations  # (U6)
    factor, weight = with_offsets(nu - innovations, sigma, covariance, slopes)  # h_i - h_mean
    r_all = predicting.noise_covariance_at(attitude)
    accepted = gate(  # (U7) per block
        nu, factor, weight, noise_subset(r_all, rows), blocks, options.gate_probability
    )
    counts["n_gated"] = float(count_blocks(blocks[~accepted]))
    if not accepted.any():
        return attitude, bias, covariance, counts, state[STATE_SIZE:]
    rows, innovations, blocks = rows[accepted], innovations[:, accepted], blocks[accepted]
    nu, factor = nu[accepted], factor[:, accepted]
    slopes = None if slopes is None else slopes[accepted]
    counts["n_used"] = float(count_blocks(blocks))
    r_all = huber_noise(r_all, rows, nu, factor, weight, blocks, options, counts)
    r = noise_subset(r_all, rows)
    posterior = covariance
    information = np.linalg.inv(covariance)
    for iteration in range(options.max_update_iterations):
        if iteration > 0:
            if not finite(state, posterior):
                break
            sigma, repaired = sigma_offsets(posterior[:STATE_SIZE, :STATE_SIZE])
            counts["covariance_repairs"] += float(repaired)
            sigma_attitudes = apply_error(state[:3] + sigma[:, :3], attitude)
            predicting = shifted(measurement, offsets, state[STATE_SIZE:])
            if offsets is not None:
                slopes = offsets.slopes(predicting, sigma_attitudes[0])[rows]
            predicted, _ = predicting.predict(sigma_attitudes, jacobian=False)
            with np.errstate(invalid="ignore"):
                innovations = predicting.innovation(predicted)[:, rows]
            # relinearised: drop blocks the model can no longer predict at some point
            lost = np.unique(blocks[~np.isfinite(innovations).all(axis=0)])
            if lost.size:
                keep_rows = ~np.isin(blocks, lost)
                rows, blocks, innovations = (
                    rows[keep_rows],
                    blocks[keep_rows],
                    innovations[:, keep_rows],
                )
                slopes = None if slopes is None else slopes[keep_rows]
                counts["n_unpredictable"] += float(lost.size)
                counts["n_used"] -= float(lost.size)
                if rows.size == 0:
                    break
                r = noise_subset(r_all, rows)
            nu = WEIGHTS @ innovations
        h, omega = regression(nu - innovations, sigma)  # pass 0: (U7)-(U8)
        if slopes is not None:
            h = np.concatenate([h, slopes], axis=1)
        noise = r + omega if r.ndim == 1 else r + np.diag(omega)
        relinearised = nu + h @ state  # the innovation relinearised at the iterate
        gain, nis, posterior = kalman_gain(covariance, h, noise, relinearised, information)
        step = gain @ relinearised - state
        state = state + step
        counts["update_iterations"] = float(iteration + 1)
        counts["nis"], counts["nis_dof"] = nis, float(rows.size)
        diagonal = r if r.ndim == 1 else np.diag(r)
        regression_exact = omega.sum() <= options.relinearise_fraction * diagonal.sum()
        if linearised(step, posterior, options.relinearise_fraction) and regression_exact:
            break
    increment = state[STATE_SIZE:]
    if not finite(state, posterior):  # reported as such: the epoch and later ones are flagged
        return attitude, bias, np.full_like(covariance, np.nan), counts, increment
    posterior, repaired = repair_covariance(carried(posterior, state))
    counts["covariance_repairs"] += float(repaired)
    attitude = apply_error(state[:3], attitude)  # (U9)
    return attitude, bias + state[3:STATE_SIZE], posterior, counts, increment


def with_offsets(
    deviation: Array, sigma: Array, covariance: Array, slopes: Array | None
) -> tuple[Array, Array]:
    """The factor ``F`` and weight ``W`` of the first pass's innovation covariance ``S =
    F^T W F + R`` (:func:`~attopt.solvers.filters.common.block_nis`, for the gate and
    the Huber weights).

    Without offsets (``slopes`` ``None``), the sigma deviations ``h_i - h_mean`` with the
    covariance weights (U7).  With them, ``F = [deviation; E^T]`` (``E`` the rows'
    ``dh / d o``, ``slopes``) and ``W = [[diag(w), Y], [Y^T, O]]``, ``O`` the
    offsets' covariance and ``Y`` ``(13, k)`` zero for the centre point and ``+/-
    L^-1 C / 2`` for the points ``+/- L_j``, so that ``deviation^T Y = H C`` (``H`` of
    :func:`regression`, ``C`` the offsets' cross-covariance): ``S`` is then (U7)'s
    plus ``H C E^T + E C^T H^T + E O E^T``, the unscented transform over the joint
    state.
    """
    weight = np.diag(COVARIANCE_WEIGHTS)
    if slopes is None:
        return deviation, weight
    n = STATE_SIZE
    spread = 0.5 * np.linalg.solve(sigma[1 : n + 1].T, covariance[:n, n:])  # L^-1 C / 2
    y = np.concatenate([np.zeros((1, spread.shape[1])), spread, -spread])
    joint_weight = np.block([[weight, y], [y.T, covariance[n:, n:]]])
    return np.concatenate([deviation, slopes.T]), joint_weight


class UsqueFilter(GyroStateFilter):
    """USQUE's state and steps (module docstring), for
    :func:`attopt.solvers.sequential.run_filter`.

    Starts at the first gyro sample with ``prior`` (``[attitude, bias]``);
    :meth:`predict` is the unscented prediction (U1)-(U5) over the gyro steps
    to a sample time or an epoch of the timeline, :meth:`update` the
    unscented update (U6)-(U9) (none while the covariance is not finite).
    """

    def predict(self, t: float) -> dict[str, float]:
        stop = self.gyro.node(t)
        self.attitude, self.bias, self.covariance, transition, repaired = propagate(
            self.attitude,
            self.bias,
            self.covariance,
            self.gyro,
            slice(self.node, stop),
            self.model,
            regress=self.offsets is not None,
        )
        self.advance(transition, stop)
        return {"gyro_gap_s": self.gyro.gap_at(stop), "covariance_repairs": float(repaired)}

    def update(self, measurement: AttitudeMeasurement | None) -> dict[str, float] | None:
        if measurement is None or not finite(self.covariance):
            return None
        covariance, rows = self.joint(measurement)
        self.attitude, self.bias, covariance, counts, increment = update(
            self.attitude, self.bias, covariance, measurement, self.options, rows
        )
        return counts | self.absorb(covariance, increment)


class UsqueOffsetFilter(UsqueFilter):
    """:class:`UsqueFilter` with transmitter offsets (:mod:`attopt.solvers.filters.offsets`),
    counting their test against the prior."""

    diagnostics = OFFSET_DIAGNOSTICS
