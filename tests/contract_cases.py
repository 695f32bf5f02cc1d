"""Problems for the contract checks over the estimator registry (``tests/test_contract.py``).

One :class:`Case` per measurement set-up; :data:`CASES` names the case every
registered estimator is checked on.  A case draws a problem (a snapshot or a
pass) with its truth, noise-free or noisy, from a seed; it also says how to
break the problem (bad input that must raise or be flagged).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.experiments.geo_snr_stations.parameters import GeoWorld
from attopt.experiments.geo_snr_stations.scenario import build_geo_snr_scenario
from attopt.formulations.attitude_measurement import EulerAngleMeasurement
from attopt.formulations.conventions import euler321_from_attitude
from attopt.formulations.geo_link import geo_snr_epoch
from attopt.formulations.passes import GyroRecord, Pass, Prior
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from tests.filter_passes import GYRO, drawn_prior, prior_covariance, simulate_pass
from tests.test_doa_ekf import drawn_prior as drawn_rate_prior
from tests.test_doa_ekf import rate_prior, simulate_vectors
from tests.test_snr_solvers import _epoch, _geometry

Problem = Snapshot | Pass
NOISE_FREE_GYRO = dataclasses.replace(GYRO, sigma_v=0.0, sigma_u=0.0, initial_bias_sigma=0.0)
"""Simulates an exact gyro (the estimators are told the noisy model, GYRO)."""


@dataclass(frozen=True)
class Drawn:
    """A problem and its truth (one rotation per epoch)."""

    problem: Problem
    truth: Rotation


@dataclass(frozen=True)
class Case:
    """A measurement set-up: ``draw(seed, noisy)``; ``broken(seed)`` is bad input;
    ``foreign(seed)`` the same epoch(s) measured by a type the estimator may not accept."""

    draw: Callable[[int, bool], Drawn]
    broken: Callable[[int], Problem]
    foreign: Callable[[int], Problem]
    tolerance: float = 1e-8
    """Largest noise-free error (rad) on the observable axes."""
    reference_prior: bool = False
    """Snapshot estimators get the truth as prior: it only sets what the data cannot see
    (a GEO boresight's yaw; without it the error's rotation vector would mix the arbitrary
    yaw into the observable axes)."""


def _truth(seed: int) -> Rotation:
    return Rotation.random(random_state=np.random.default_rng(seed))


def _euler_snapshot(truth: Rotation) -> Snapshot:
    return Snapshot.of(EulerAngleMeasurement(euler321_from_attitude(truth), 1e-4 * np.eye(3)))


# --- unit vectors -----------------------------------------------------------------------------

REFERENCES = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.48, -0.6, 0.64]])
VECTOR_SIGMA = np.array([1e-3, 2e-3, 3e-3])


def _vector_draw(seed: int, noisy: bool) -> Drawn:
    truth = _truth(seed)
    body = truth.apply(REFERENCES)
    if noisy:
        rng = np.random.default_rng(seed + 1)
        body = body + VECTOR_SIGMA[:, None] * rng.standard_normal(body.shape)
    return Drawn(Snapshot.from_vectors(body, REFERENCES, VECTOR_SIGMA), truth)


def _vector_broken(seed: int) -> Snapshot:
    """One vector left after the NaN one is dropped: the attitude is not determined."""
    body = _truth(seed).apply(REFERENCES[:2])
    body[1] = np.nan
    return Snapshot.from_vectors(body, REFERENCES[:2], VECTOR_SIGMA[:2])


VECTORS = Case(_vector_draw, _vector_broken, lambda seed: _euler_snapshot(_truth(seed)))
VECTORS_GENERIC = dataclasses.replace(VECTORS, broken=lambda seed: Snapshot(()))
"""For the MAP NLP one vector is not bad input (it reports the axes it cannot see as
unobservable, ``tests/test_contract.py``); a snapshot without measurements is."""


# --- SNRs of ADS-B messages at two antennas (Liu et al. 2023) ----------------------------------


def _snr_epoch(seed: int, noisy: bool, **options: float) -> tuple[SnrEpoch, Rotation]:
    truth = _truth(seed)
    rng = np.random.default_rng(seed + 1)
    geometry = _geometry(rng, truth)
    true_snr = geometry[3]
    snr = true_snr + rng.standard_normal(true_snr.shape) if noisy else true_snr
    return _epoch(geometry, snr, **options), truth


def _snr_case(**options: float) -> Case:
    def draw(seed: int, noisy: bool) -> Drawn:
        epoch, truth = _snr_epoch(seed, noisy, **options)
        return Drawn(Snapshot.of(SnrMeasurement(epoch)), truth)

    def broken(seed: int) -> Snapshot:
        epoch, _ = _snr_epoch(seed, False, **options)
        snr = epoch.snr_db.copy()
        snr[0] = np.nan
        return Snapshot.of(SnrMeasurement(dataclasses.replace(epoch, snr_db=snr)))

    return Case(draw, broken, lambda seed: _euler_snapshot(_truth(seed)))


ADSB = _snr_case()
ADSB_UNTRUNCATED = _snr_case(threshold_db=-np.inf)
"""Without a reception threshold the truncated likelihood is eq. 19's: noise-free exact."""


# --- SNRs of a GEO broadcaster at ground stations (Pimienta-Penalver and Crassidis) ------------


@cache
def _geo_scenario():
    return build_geo_snr_scenario(GeoWorld(step_s=600.0), manoeuvre=False)


def _geo_draw(seed: int, noisy: bool) -> Drawn:
    scenario = _geo_scenario()
    k = seed % scenario.t.size
    heard = np.flatnonzero(scenario.heard[k])
    snr = scenario.true_snr_db[k, heard]
    if noisy:
        snr = snr + scenario.snr_sigma_db * np.random.default_rng(seed).standard_normal(snr.shape)
    epoch = geo_snr_epoch(
        snr, scenario.satellite_eci_km[k], scenario.stations_eci_km[k, heard], scenario.snr_sigma_db
    )
    return Drawn(Snapshot.of(SnrMeasurement(epoch)), scenario.truth[k])


def _geo_broken(seed: int) -> Snapshot:
    """Two stations: the cones meet in two directions, the boresight is not determined."""
    scenario = _geo_scenario()
    k = seed % scenario.t.size
    heard = np.flatnonzero(scenario.heard[k])[:2]
    epoch = geo_snr_epoch(
        scenario.true_snr_db[k, heard],
        scenario.satellite_eci_km[k],
        scenario.stations_eci_km[k, heard],
        scenario.snr_sigma_db,
    )
    return Snapshot.of(SnrMeasurement(epoch))


GEO = Case(
    _geo_draw,
    _geo_broken,
    lambda seed: _euler_snapshot(_truth(seed)),
    tolerance=1e-7,
    reference_prior=True,
)


# --- gyro and unit vectors over a pass ------------------------------------------------------------

PASS_S = 20.0


def _gyro_draw(seed: int, noisy: bool) -> Drawn:
    rng = np.random.default_rng(seed)
    simulated = GYRO if noisy else NOISE_FREE_GYRO
    run = simulate_pass(rng, duration=PASS_S, noisy=noisy, simulated_gyro=simulated)
    covariance = prior_covariance(np.radians(1.0))
    if noisy:
        prior = drawn_prior(rng, run, covariance)
    else:
        prior = Prior(run.truth[0], covariance, bias=run.bias[0])
    gyro = GyroRecord(run.gyro.t, run.gyro.rates, GYRO)
    return Drawn(Pass.from_measurements(run.t, run.measurements, gyro, prior), run.truth_at_epochs)


def _gyro_broken(seed: int) -> Pass:
    """The pass without its gyro record."""
    drawn = _gyro_draw(seed, False).problem
    return Pass(drawn.t, drawn.snapshots, None, drawn.prior)


def _gyro_foreign(seed: int) -> Pass:
    drawn = _gyro_draw(seed, False)
    snapshots = [_euler_snapshot(drawn.truth[k]) for k in range(len(drawn.truth))]
    return Pass(drawn.problem.t, snapshots, drawn.problem.gyro, drawn.problem.prior)


GYRO_VECTORS = Case(_gyro_draw, _gyro_broken, _gyro_foreign)


# --- rigid-body dynamics and unit vectors (Yang et al. 2014) ------------------------------------

DYNAMICS_EPOCHS = 40


def _dynamics_draw(seed: int, noisy: bool) -> Drawn:
    rng = np.random.default_rng(seed)
    run = simulate_vectors(rng, DYNAMICS_EPOCHS, noisy=noisy, presence=1.0)
    covariance = np.diag([1e-6] * 3 + [np.radians(1.0) ** 2] * 3)
    if noisy:
        prior = drawn_rate_prior(rng, run, covariance)
    else:
        prior = rate_prior(run.truth[0], run.rate[0], covariance)
    return Drawn(run.pass_(prior), run.truth)


def _dynamics_broken(seed: int) -> Pass:
    """The pass without its dynamics."""
    drawn = _dynamics_draw(seed, False).problem
    return Pass(drawn.t, drawn.snapshots, None, drawn.prior)


def _dynamics_foreign(seed: int) -> Pass:
    drawn = _dynamics_draw(seed, False)
    snapshots = [_euler_snapshot(drawn.truth[k]) for k in range(len(drawn.truth))]
    pass_ = drawn.problem
    return Pass(pass_.t, snapshots, None, pass_.prior, pass_.dynamics)


DYNAMICS_VECTORS = Case(_dynamics_draw, _dynamics_broken, _dynamics_foreign)


# --- gyro and SNRs with transmitter identities (the power-offset smoother) -------------------


def _gyro_snr_draw(seed: int, noisy: bool) -> Drawn:
    rng = np.random.default_rng(seed)
    drawn = _gyro_draw(seed, noisy)
    pass_ = drawn.problem
    snapshots = []
    for k in range(len(pass_)):
        geometry = _geometry(rng, drawn.truth[k], per_antenna=(6, 6))
        true_snr = geometry[3]
        snr = true_snr + rng.standard_normal(true_snr.shape) if noisy else true_snr
        epoch = _epoch(geometry, snr, threshold_db=-np.inf, transmitter=np.arange(snr.size))
        snapshots.append(Snapshot.of(SnrMeasurement(epoch)))
    return Drawn(Pass(pass_.t, snapshots, pass_.gyro, pass_.prior), drawn.truth)


GYRO_SNRS = Case(_gyro_snr_draw, _gyro_broken, _gyro_foreign, tolerance=1e-7)


CASES: dict[str, Case] = {
    **dict.fromkeys(("triad", "svd", "q_method", "quest", "foam", "sdp"), VECTORS),
    "map_nlp": VECTORS_GENERIC,
    **dict.fromkeys(("deterministic", "nlse", "nlp"), ADSB),
    "nlp_truncated": ADSB_UNTRUNCATED,
    **dict.fromkeys(("geo_cone", "geo_lsq"), GEO),
    **dict.fromkeys(("mekf", "usque", "rts", "fg_online", "fg_batch"), GYRO_VECTORS),
    **dict.fromkeys(("fg_batch_offsets", "mekf_offsets", "usque_offsets"), GYRO_SNRS),
    **dict.fromkeys(("ekf_yang2014", "rts_yang2014", "bls_yang2014"), DYNAMICS_VECTORS),
}
