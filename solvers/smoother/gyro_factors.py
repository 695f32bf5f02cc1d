"""Gyro, bias and prior factors of the smoother (built-in GTSAM factors).

Between consecutive nodes ``i`` and ``i + 1`` (boundaries ``t_i``, ``t_{i+1}``
of the gyro timeline, :mod:`attopt.solvers.gyro_timeline`: gyro sample times or
epochs between them; ``T = t_{i+1} - t_i``):

* ``gtsam.AHRSFactor(x_i, x_{i+1}, b_i, pim)`` with the
  ``PreintegratedAhrsMeasurements`` of the timeline's steps in ``[t_i, t_{i+1})``:
  ``Delta R = prod_j Exp((omega_j - b_hat) dt_j)``, zero error when ``R_{i+1}
  = R_i Delta R(b_i)`` (first-order bias correction about ``b_hat``).  With
  ``R = A^T`` this is ``A_{i+1} = prod_j exp(-[(omega_j - b) x] dt) A_i``,
  exactly :func:`attopt.formulations.gyro.attitude_increment` step by step (pinned
  by ``tests/test_smoother.py`` with a noise-free gyro).  ``b_hat`` is the
  bias estimate of node ``i`` when the graph is built; the driver rebuilds
  the graph when an estimate moves by more than
  ``GraphOptions.bias_relinearise_angle / T`` from it, so the first-order
  correction is exact to second order at the solution;
* noise of the AHRS factor: ``(sigma_v^2 T + sigma_u^2 T^3 / 3 + h) I``, set
  through ``PreintegratedRotationParams.setGyroscopeCovariance`` (a
  continuous-time density, integrated to ``density * T`` by GTSAM; every
  term is isotropic, so the preintegrated covariance is exactly that).
  ``sigma_v^2 T`` is the angle random walk, ``sigma_u^2 T^3 / 3`` the
  attitude effect of the bias wandering within the interval while the factor
  holds ``b_i`` (Markley and Crassidis 2014, eq. 6.93's ``Q11``; its
  correlation with the bias step, ``Q12``, is neglected: the correlation
  coefficient is ``sigma_u T / (2 sqrt(sigma_v^2 + sigma_u^2 T^2 / 3))``,
  8e-5 for the MEMS gyro over 1 s, 0.43 for Liu et al. 2023's), ``h`` the gyro-gap growth of
  :func:`attopt.solvers.filters.common.prepare_gyro` summed over the interval (the
  filters' rule: a missing sample is replaced by the last valid one, and a
  gap of ``T_g`` adds ``(sigma_hold T_g)^2``);
* bias random walk: ``gtsam.BetweenFactorVector(b_i, b_{i+1}, 0,
  sigma_u sqrt(T))`` (Liu et al. 2023 eq. 24).

The prior (:class:`JointPrior`) is the full ``6 x 6`` covariance of the
``[attitude, bias]`` :class:`~attopt.formulations.passes.Prior`, attitude-bias
cross terms included: the errors of ``gtsam.PriorFactorRot3`` and ``PriorFactorVector``
(linearised by GTSAM) whitened jointly.  ``PriorFactorRot3``'s error is
``Logmap(R_prior^-1 R) = -rotvec(A A_prior^T)``, the opposite of attopt's
``delta``, so its covariance is ``T P T`` with ``T = diag(-I, I)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gyro import GyroModel
from attopt.formulations.passes import Prior
from attopt.solvers.filters.common import PreparedGyro
from attopt.solvers.smoother.conventions import SIGN, Array, attitude_key, bias_key, rot3

UNIT3 = gtsam.noiseModel.Unit.Create(3)


def check_model(model: GyroModel) -> None:
    """The smoother needs positive noise densities (its factors' covariances)."""
    if not (model.sigma_v > 0 and model.sigma_u > 0):
        raise InvalidObservationError(
            f"the smoother needs sigma_v > 0 and sigma_u > 0 (gyro model {model.name!r})"
        )


@dataclass(frozen=True)
class GyroIntervals:
    """The gyro steps between consecutive nodes and their extra variances."""

    nodes: Array
    """``(n,)`` index of each node into the gyro timeline's boundaries."""
    duration: Array
    """``(n - 1,)`` interval lengths ``T`` (s)."""
    attitude_variance: Array
    """``(n - 1,)`` AHRS factor variance per axis (rad^2)."""
    bias_sigma: Array
    """``(n - 1,)`` bias random-walk standard deviation ``sigma_u sqrt(T)`` (rad/s)."""
    broken: NDArray[np.bool_]
    """``(n - 1,)`` intervals inside a gyro gap longer than the limit: no AHRS factor."""

    @property
    def segment_starts(self) -> NDArray[np.intp]:
        """Nodes after a broken interval: each starts a new attitude segment."""
        return np.flatnonzero(self.broken) + 1


def long_gap_steps(gyro: PreparedGyro, max_gap_s: float) -> NDArray[np.bool_]:
    """``(n - 1,)`` gyro steps inside a run of missing samples longer than ``max_gap_s``."""
    missing = gyro.gap_s > 0
    if not missing.any():
        return missing
    starts = missing & ~np.concatenate([[False], missing[:-1]])
    ends = missing & ~np.concatenate([missing[1:], [False]])
    run = np.cumsum(starts) - 1
    return missing & (gyro.gap_s[ends][run.clip(0)] > max_gap_s)


def gyro_intervals(
    nodes: Array, gyro: PreparedGyro, model: GyroModel, max_gap_s: float = np.inf
) -> GyroIntervals:
    """Noise of each interval's factors (module docstring); intervals that contain a
    step of a gyro gap longer than ``max_gap_s`` are broken."""
    nodes = np.asarray(nodes)
    duration = gyro.timeline.durations(nodes)
    hold = (
        np.add.reduceat(gyro.hold_variance[: nodes[-1]], nodes[:-1])
        if nodes.size > 1
        else np.zeros(0)
    )
    variance = model.sigma_v**2 * duration + model.sigma_u**2 * duration**3 / 3.0 + hold
    long = long_gap_steps(gyro, max_gap_s)
    broken = (
        np.logical_or.reduceat(long[: nodes[-1]], nodes[:-1])
        if nodes.size > 1
        else np.zeros(0, dtype=bool)
    )
    return GyroIntervals(nodes, duration, variance, model.sigma_u * np.sqrt(duration), broken)


def gyro_graph(
    intervals: GyroIntervals, gyro: PreparedGyro, bias_hat: Array
) -> gtsam.NonlinearFactorGraph:
    """AHRS and bias random-walk factors between all consecutive nodes (no AHRS
    factor over a broken interval: the gyro says nothing there, so the attitude
    segments on either side are not linked; the bias walk still links them).

    ``bias_hat`` ``(n, 3)``: the bias about which interval ``i`` is
    preintegrated (node ``i``'s estimate).
    """
    graph = gtsam.NonlinearFactorGraph()
    params: dict[float, gtsam.PreintegratedRotationParams] = {}
    nodes = intervals.nodes
    for i in range(nodes.size - 1):
        density = float(intervals.attitude_variance[i] / intervals.duration[i])
        if density not in params:
            p = gtsam.PreintegratedRotationParams()
            p.setGyroscopeCovariance(density * np.eye(3))
            params[density] = p
        if not intervals.broken[i]:
            pim = gtsam.PreintegratedAhrsMeasurements(params[density], np.asarray(bias_hat[i]))
            steps = slice(nodes[i], nodes[i + 1])
            for rate, dt in zip(gyro.rates[steps], gyro.dt[steps], strict=True):
                pim.integrateMeasurement(rate, dt)
            graph.add(gtsam.AHRSFactor(attitude_key(i), attitude_key(i + 1), bias_key(i), pim))
        graph.add(
            gtsam.BetweenFactorVector(
                bias_key(i),
                bias_key(i + 1),
                np.zeros(3),
                gtsam.noiseModel.Isotropic.Sigma(3, float(intervals.bias_sigma[i])),
            )
        )
    return graph


class JointPrior:
    """The prior on node 0's attitude and bias with its full ``6 x 6`` covariance."""

    def __init__(self, prior: Prior) -> None:
        self.attitude = prior.attitude
        self.bias = np.asarray(prior.bias, dtype=float)
        self.rotation_factor = gtsam.PriorFactorRot3(attitude_key(0), rot3(prior.attitude), UNIT3)
        self.bias_factor = gtsam.PriorFactorVector(bias_key(0), self.bias, UNIT3)
        covariance = SIGN @ np.asarray(prior.covariance, dtype=float) @ SIGN
        self.cholesky = np.linalg.cholesky(0.5 * (covariance + covariance.T))

    def whiten(self, x: Array) -> Array:
        return solve_triangular(self.cholesky, x, lower=True)

    def error(self, values: gtsam.Values) -> Array:
        """Unwhitened ``[Logmap(R_prior^-1 R), b - b_prior]``."""
        return np.concatenate(
            [self.rotation_factor.unwhitenedError(values), self.bias_factor.unwhitenedError(values)]
        )

    def whitened_error(self, values: gtsam.Values) -> Array:
        return self.whiten(self.error(values))

    def cost(self, values: gtsam.Values) -> float:
        r = self.whitened_error(values)
        return 0.5 * float(r @ r)

    def linearize(self, values: gtsam.Values) -> gtsam.JacobianFactor:
        """The whitened linear factor on ``(x_0, b_0)`` at ``values``."""
        h = np.zeros((6, 6))
        # getA() is a view without keep-alive: keep the factor alive while copying
        linear = gtsam.JacobianFactor(self.rotation_factor.linearize(values))
        h[:3, :3] = np.array(linear.getA())
        h[3:, 3:] = np.eye(3)
        a = self.whiten(h)
        b = -self.whitened_error(values)
        return gtsam.JacobianFactor(
            attitude_key(0), a[:, :3], bias_key(0), a[:, 3:], b, gtsam.noiseModel.Unit.Create(6)
        )
