"""Rate-integrating gyro model of Liu et al. 2023 eqs. 23-25 and its exact discretisation.

Continuous model (Liu et al. 2023 eqs. 23-25; Markley and Crassidis 2014, sec. 4.7)::

    omega_measured = omega + beta + eta_v,     d beta / dt = eta_u,

``omega`` the true body rate relative to the reference (inertial) frame,
expressed in the body frame, ``beta`` the bias, ``eta_v`` and ``eta_u``
independent white noises with power spectral densities ``sigma_v^2 I`` and
``sigma_u^2 I``.  Units: ``sigma_v`` in rad/s^(1/2) (angle random walk),
``sigma_u`` in rad/s^(3/2) (rate random walk), rates in rad/s.

Liu et al. 2023 sec. 5.1 gives "sigma_v = sigma_u = 0.05 deg/s" without time units.
attopt reads both as spectral densities with the SI second, ``sigma_v = 0.05
deg/s^(1/2)`` and ``sigma_u = 0.05 deg/s^(3/2)`` (:data:`LIU2023_GYRO`):
this is also what a discrete filter at the paper's 1 s step with ``Q_k = Q``
(eqs. 38-39, no ``T`` factor) assumes.  The rate random walk is enormous
(the bias wanders by ``0.05 sqrt(3600) = 3 deg/s`` per axis in an hour), so
the gyro contributes little beyond short-term smoothing; :data:`MEMS_GYRO` is
a realistic MEMS-class unit for comparison (angle random walk 0.3
deg/h^(1/2), rate random walk 10 deg/h per h^(1/2)).

Samples.  The gyro is rate integrating: sample ``j`` is the mean measured
rate over ``[t_j, t_j + dt)``, ``(theta_{j+1} - theta_j) / dt``.  Its exact
distribution given the true motion is (Markley and Crassidis 2014, eqs.
6.90-6.91; the bias integral conditioned on its end points is a Brownian
bridge)::

    omega_j = omega_bar_j + (beta_j + beta_{j+1}) / 2
              + sqrt(sigma_v^2 / dt + sigma_u^2 dt / 12) n_v,
    beta_{j+1} = beta_j + sigma_u sqrt(dt) n_u,

with ``omega_bar_j`` the constant rate that carries the true attitude from
``t_j`` to ``t_j + dt`` and ``n_v, n_u ~ N(0, I3)`` independent
(:func:`simulate_gyro`).  The initial bias is drawn from ``N(0,
initial_bias_sigma^2 I3)``.

Error-state model of the multiplicative filters (Liu et al. 2023 eqs. 36-39): state
``[delta, delta_beta]`` with ``A_true = exp(delta) A_est`` (the body-frame
error of ``docs/conventions.md``) and ``delta_beta = beta - beta_hat``.
From ``dA/dt = -[omega x] A`` for both attitudes, ``d exp(delta)/dt =
[(omega_hat - omega) x] - [(omega x delta) x]`` to first order, and
``omega_hat - omega = delta_beta + eta_v``, so::

    d delta / dt = -[omega_hat x] delta + delta_beta + eta_v.

Liu et al. 2023 eq. 36 (and Markley and Crassidis eq. 6.75) print ``- delta_beta -
eta_v``, which belongs to their quaternion-product convention; with attopt's
convention the sign is ``+`` (pinned by the bias-convergence and Van Loan
tests: the other sign drives the bias estimate away from the truth).  The
discrete transition over a step with constant estimated rate is
:func:`error_state_transition` (closed form of ``expm(F dt)``) and the process
noise :meth:`GyroModel.process_noise` (Markley and Crassidis 2014, eq. 6.93,
``Q12`` with the sign of this convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]

SERIES_LIMIT = 1e-3
"""Below this ``|omega dt|`` (rad) the closed forms use their Taylor series."""


@dataclass(frozen=True)
class GyroModel:
    """Gyro noise and bias statistics (module docstring for units and sources).

    Attributes:
        name: label used in experiment tables.
        sigma_v: angle random walk, rad/s^(1/2).
        sigma_u: rate random walk, rad/s^(3/2).
        initial_bias_sigma: standard deviation of each initial bias component, rad/s.
        rate_hz: sampling rate.

    Example::

        >>> import numpy as np
        >>> from attopt import GyroModel
        >>> deg = np.radians(1.0)
        >>> tactical = GyroModel(
        ...     "tactical", sigma_v=0.05 * deg / 60, sigma_u=deg / 3600 / 60,
        ...     initial_bias_sigma=deg / 3600, rate_hz=100.0,
        ... )
        >>> tactical.dt, tactical.process_noise(tactical.dt).shape
        (0.01, (6, 6))
    """

    name: str
    sigma_v: float
    sigma_u: float
    initial_bias_sigma: float
    rate_hz: float = 10.0

    def __post_init__(self) -> None:
        values = (self.sigma_v, self.sigma_u, self.initial_bias_sigma, self.rate_hz)
        if not all(np.isfinite(v) and v >= 0 for v in values) or self.rate_hz <= 0:
            raise ValueError(f"gyro statistics must be finite and non-negative: {self}")

    @property
    def dt(self) -> float:
        """Sampling interval (s)."""
        return 1.0 / self.rate_hz

    def process_noise(self, dt: float) -> Array:
        """Discrete process noise ``Q`` of the 6-state error model over ``dt``.

        ``Q11 = (sigma_v^2 dt + sigma_u^2 dt^3 / 3) I``, ``Q12 = +(sigma_u^2 dt^2 / 2) I``,
        ``Q22 = sigma_u^2 dt I`` (Markley and Crassidis 2014, eq. 6.93, with
        the sign of ``Q12`` of this module's error convention): exact for a
        non-rotating body, first order in ``|omega| dt`` otherwise.
        """
        v2, u2 = self.sigma_v**2, self.sigma_u**2
        eye = np.eye(3)
        q11 = (v2 * dt + u2 * dt**3 / 3.0) * eye
        q12 = (u2 * dt**2 / 2.0) * eye
        return np.block([[q11, q12], [q12, u2 * dt * eye]])


DEG = np.pi / 180.0

LIU2023_GYRO = GyroModel(
    name="liu2023", sigma_v=0.05 * DEG, sigma_u=0.05 * DEG, initial_bias_sigma=0.1 * DEG
)
"""Liu et al. 2023 sec. 5.1 read literally (module docstring); initial bias 0.1 deg/s (not in
the paper)."""

MEMS_GYRO = GyroModel(
    name="mems",
    sigma_v=0.3 * DEG / 60.0,
    sigma_u=10.0 * DEG / 3600.0 / 60.0,
    initial_bias_sigma=0.1 * DEG,
)
"""MEMS class: 0.3 deg/h^(1/2) angle random walk, 10 deg/h per h^(1/2) rate random
walk, 0.1 deg/s (360 deg/h) turn-on bias."""

GYRO_MODELS = {model.name: model for model in (LIU2023_GYRO, MEMS_GYRO)}


def _cross_matrices(w: Array) -> Array:
    """``[w x]`` for ``(..., 3)`` vectors -> ``(..., 3, 3)``."""
    zero = np.zeros(w.shape[:-1])
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    return np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(*w.shape[:-1], 3, 3)


def error_state_transition(rate: ArrayLike, dt: ArrayLike) -> Array:
    """Transition ``Phi = expm(F dt)`` of the error state over one step, ``(..., 6, 6)``.

    ``F = [[-[w x], I], [0, 0]]`` with ``w`` the estimated rate ``(..., 3)``
    held over the step; ``dt`` the step (s), or one per rate shaped ``(..., 1,
    1)``.  ``Phi11 = exp(-[w x] dt)`` (the rotation matrix of the attitude
    increment) and ``Phi12 = int_0^dt exp(-[w x] s) ds``
    (Markley and Crassidis 2014, eqs. 6.83-6.84), by Taylor series below
    :data:`SERIES_LIMIT`.
    """
    w = np.asarray(rate, dtype=float)
    angle = np.linalg.norm(w, axis=-1)[..., None, None] * dt
    cross = _cross_matrices(w) * dt
    cross2 = cross @ cross
    small = angle < SERIES_LIMIT
    safe = np.where(small, 1.0, angle)
    # (1 - cos x) / x^2 and (x - sin x) / x^3 and sin x / x
    c1 = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    c2 = np.where(small, 1.0 / 6.0 - angle**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    s1 = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    eye = np.eye(3)
    phi11 = eye - s1 * cross + c1 * cross2
    phi12 = (eye - c1 * cross + c2 * cross2) * dt
    shape = w.shape[:-1]
    phi = np.zeros((*shape, 6, 6))
    phi[..., :3, :3] = phi11
    phi[..., :3, 3:] = phi12
    phi[..., 3:, 3:] = eye
    return phi


def attitude_increment(rate: ArrayLike, dt: ArrayLike) -> Rotation:
    """Rotation ``exp(-[w x] dt)`` that carries the attitude over a step at rate ``w``
    (``dt`` the step, s, or steps broadcastable against the rates).

    With ``A`` mapping reference to body, ``dA/dt = -[w x] A``, so
    ``A(t + dt) = exp(-[w x] dt) A(t)`` for a constant rate.
    """
    return Rotation.from_rotvec(-np.asarray(rate, dtype=float) * dt)


def mean_rates(truth: Rotation, dt: float) -> Array:
    """Constant rates ``omega_bar_j`` carrying ``truth[j]`` to ``truth[j + 1]``, ``(n - 1, 3)``."""
    return -(truth[1:] * truth[:-1].inv()).as_rotvec() / dt


@dataclass(frozen=True)
class GyroSamples:
    """Gyro record of a pass.

    Attributes:
        t: ``(n,)`` sample times (s), uniform step ``dt``.
        rates: ``(n - 1, 3)`` measured mean rates over ``[t_j, t_{j+1})`` (rad/s);
            NaN rows are missing samples.
        dt: the step (s).
    """

    t: Array
    rates: Array
    dt: float


@dataclass(frozen=True)
class SimulatedGyro:
    """:class:`GyroSamples` with the truth they were drawn from."""

    samples: GyroSamples
    true_rates: Array
    """``(n - 1, 3)`` ``omega_bar_j``."""
    bias: Array
    """``(n, 3)`` true bias at the sample times."""


def simulate_gyro(
    t: ArrayLike, truth: Rotation, model: GyroModel, rng: np.random.Generator
) -> SimulatedGyro:
    """Gyro samples of the true attitudes ``truth`` (reference -> body) at times ``t``.

    Exact discrete statistics of the module docstring; ``t`` must be uniform
    with step ``model.dt``.  The draws are, in order: initial bias, bias steps,
    rate noise.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import MEMS_GYRO, simulate_gyro
        >>> t = np.arange(0.0, 10.01, MEMS_GYRO.dt)
        >>> truth = Rotation.from_rotvec(-np.outer(t, [0.0, 0.0, 0.01]))  # 0.01 rad/s about z
        >>> gyro = simulate_gyro(t, truth, MEMS_GYRO, np.random.default_rng(0))
        >>> gyro.samples.rates.shape, bool(np.allclose(gyro.true_rates[:, 2], 0.01))
        ((100, 3), True)
    """
    t = np.asarray(t, dtype=float)
    dt = model.dt
    if t.ndim != 1 or t.size < 2 or not np.allclose(np.diff(t), dt, rtol=0, atol=1e-9 * dt):
        raise ValueError(f"gyro times must be uniform with step {dt} s")
    n = t.size
    initial = model.initial_bias_sigma * rng.standard_normal(3)
    steps = model.sigma_u * np.sqrt(dt) * rng.standard_normal((n - 1, 3))
    bias = initial + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    white = np.sqrt(model.sigma_v**2 / dt + model.sigma_u**2 * dt / 12.0)
    true_rates = mean_rates(truth, dt)
    measured = true_rates + 0.5 * (bias[:-1] + bias[1:]) + white * rng.standard_normal((n - 1, 3))
    return SimulatedGyro(GyroSamples(t, measured, dt), true_rates, bias)
