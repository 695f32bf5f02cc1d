"""Each method's estimates in ``geo-snr-stations`` as rows of a pointing (boresight) error.

A :class:`Pointing` holds one method's estimates at the ``N`` epochs and turns them into
the rows (columns: :mod:`attopt.experiments.geo_snr_stations.experiment`).  The
snapshot boresight estimators (:func:`boresight_pointing`) and the one-step SNR solvers
started from the least-squares boresight (:func:`one_step_pointing`) carry the
Cramer-Rao bound of their stations' SNRs (:func:`crb_sigma`); the filters and smoothers
(:func:`track_pointing`) their own sigma.  NEES (:func:`pointing_nees`): over the two
axes across the boresight for every method, the axes the SNRs see.  The boresight
methods' variance about the boresight is infinite; the filters' and smoothers' yaw
rests on the prior carried by the assumed rates, which no SNR can check (after an
unmodelled manoeuvre it is wrong by the manoeuvre's angle with no sign in the
innovations, ``docs/geo.md``), so its normalised error is kept apart
(``yaw_nees``, 1 dof), for the record.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.geo_snr_stations.scenario import GeoSnrScenario
from attopt.experiments.metrics import attitude_columns, pointing_error
from attopt.formulations.errors import AttoptError
from attopt.formulations.geo_fisher import snr_fisher_information
from attopt.formulations.geo_link import BORESIGHT_BODY, attitude_pointing
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.geo.boresight import check_elevations, estimated_boresight
from attopt.solvers.registry import estimator
from attopt.solvers.results import Track, observable_sigma
from attopt.solvers.snr.one_step import OneStepSolver

Array = NDArray[np.float64]
POINTING_DOF = 2
"""Degrees of freedom of a boresight's NEES (:func:`pointing_nees`)."""


@dataclass
class Pointing:
    """One method's estimates at the ``N`` epochs: boresights ``(N, 3)`` (ECI), the stored
    quaternions ``(N, 4)`` (ECI -> body, scipy scalar-last), ``sigma`` ``(N, 3)`` rad,
    ``bound`` ``(N, 2)`` rad, the filters' ``yaw`` error (rad), ``nees`` over the
    :data:`POINTING_DOF` axes across the boresight, the stations whose
    SNRs the method was given (``n_stations``), the ``reason`` of each epoch without
    estimate and extra columns."""

    boresight: Array
    quaternion: Array
    sigma: Array
    bound: Array
    yaw: Array
    nees: Array
    n_stations: NDArray[np.intp]
    reason: NDArray[np.object_]
    extra: dict[str, Array] = field(default_factory=dict)

    @classmethod
    def empty(cls, n_stations: NDArray[np.intp]) -> Pointing:
        """No estimate at any epoch, the method given ``n_stations`` SNRs at each."""
        n = n_stations.size
        return cls(
            np.full((n, 3), np.nan),
            np.full((n, 4), np.nan),
            np.full((n, 3), np.nan),
            np.full((n, 2), np.nan),
            np.full(n, np.nan),
            np.full(n, np.nan),
            n_stations,
            np.full(n, "", dtype=object),
        )

    @classmethod
    def failed(cls, n_stations: NDArray[np.intp], reason: str) -> Pointing:
        """No estimate at any epoch, for ``reason`` (a pass estimator that cannot run)."""
        pointing = cls.empty(n_stations)
        pointing.reason[:] = reason
        return pointing

    def frame(self, label: str, scenario: GeoSnrScenario) -> pd.DataFrame:
        """The rows: pointing error, sigmas, bounds, the filters' yaw error, validity, the
        estimated and true quaternions, NEES and station count."""
        valid = np.isfinite(self.boresight).all(axis=1)
        error = np.full_like(self.boresight, np.nan)
        error[valid] = pointing_error(scenario.truth[valid], self.boresight[valid])
        columns: dict[str, Any] = {"method": label, "t_s": scenario.t}
        for i, axis in enumerate("xyz"):
            columns[f"err_{axis}_deg"] = np.degrees(error[:, i])
        for i, axis in enumerate("xyz"):
            columns[f"sigma_{axis}_deg"] = np.degrees(self.sigma[:, i])
        for i, axis in enumerate("xy"):
            columns[f"bound_{axis}_deg"] = np.degrees(self.bound[:, i])
        columns |= {
            "yaw_err_deg": np.degrees(self.yaw),
            "yaw_observable": False,
            "valid": valid,
            "reason": np.where(valid, "", self.reason),
            **attitude_columns(np.where(valid[:, None], self.quaternion, np.nan), scenario.truth),
            "nees": np.where(valid, self.nees, np.nan),
            "nees_dof": POINTING_DOF,
            "n_stations": self.n_stations,
            **self.extra,
        }
        return pd.DataFrame(columns)


def crb_sigma(scenario: GeoSnrScenario, k: int, stations: NDArray[np.intp]) -> Array:
    """Cramer-Rao standard deviations (rad) about body x, y of epoch ``k``'s ``stations``."""
    fisher = snr_fisher_information(
        scenario.truth[k],
        scenario.satellite_eci_km[k],
        scenario.stations_eci_km[k, stations],
        scenario.snr_sigma_db,
        scenario.link,
    )
    return np.sqrt(np.diag(np.linalg.pinv(fisher, rcond=1e-9, hermitian=True))[:2])


def pointing_nees(estimate: Rotation, truth: Rotation, covariance: Array) -> Array:
    """``(N,)`` NEES over the two axes across the boresight: ``e^T P^-1 e`` with ``e`` the
    smallest rotation carrying the estimated boresight onto the true one, in the estimated
    body frame (:func:`~attopt.experiments.metrics.pointing_error`), and ``P`` the x-y block
    of the estimator's covariance (body frame; its variance about the boresight is
    infinite)."""
    error = pointing_error(estimate, truth.inv().apply(BORESIGHT_BODY))[:, :2]
    block = np.asarray(covariance, dtype=float)[:, :2, :2]
    return np.einsum("ei,eij,ej->e", error, np.linalg.inv(block), error)


def epoch_snapshot(
    scenario: GeoSnrScenario, snr: Array, k: int, stations: NDArray[np.intp]
) -> Snapshot:
    """Epoch ``k``'s ``stations``' measured SNRs (``snr`` ``(N, m)``) as a snapshot; raises
    :class:`~attopt.formulations.errors.InvalidObservationError` for a station that does
    not see the satellite."""
    check_elevations(
        scenario.stations_eci_km[k, stations],
        scenario.stations_up_eci[k, stations],
        scenario.satellite_eci_km[k],
    )
    epoch = scenario.epoch(k, snr[k, stations], stations)
    return Snapshot.of(SnrMeasurement(epoch), t=float(scenario.t[k]))


def station_snapshots(
    scenario: GeoSnrScenario, snr: Array, stations: list[NDArray[np.intp]]
) -> tuple[list[Snapshot | None], NDArray[np.object_]]:
    """Each epoch's SNRs of its ``stations`` as a snapshot (:func:`epoch_snapshot`), and
    the reason of the epochs that have none."""
    snapshots: list[Snapshot | None] = []
    reason = np.full(scenario.t.size, "", dtype=object)
    for k, chosen in enumerate(stations):
        try:
            snapshots.append(epoch_snapshot(scenario, snr, k, chosen))
        except AttoptError as error:
            snapshots.append(None)
            reason[k] = str(error)
    return snapshots, reason


def station_counts(stations: list[NDArray[np.intp]]) -> NDArray[np.intp]:
    """The number of stations of each epoch."""
    return np.array([chosen.size for chosen in stations], dtype=np.intp)


def boresight_pointing(
    name: str, scenario: GeoSnrScenario, snr: Array, stations: list[NDArray[np.intp]]
) -> Pointing:
    """Registry boresight estimator ``name`` over the epochs, each on its ``stations``,
    with the Cramer-Rao bound of those stations' SNRs where it has an estimate.  Its
    attitude is the smallest rotation taking the boresight to body ``+z`` (the estimator's,
    without a prior): the yaw about the boresight is a convention, not an estimate."""
    snapshots, reason = station_snapshots(scenario, snr, stations)
    track = estimator(name).solve_sequence(snapshots)
    pointing = Pointing.empty(station_counts(stations))
    pointing.reason = np.where(reason != "", reason, track.reason)
    valid = track.valid
    pointing.boresight[valid] = estimated_boresight(track)[valid]
    pointing.quaternion[valid] = track.quaternion[valid]
    if valid.any():
        estimate = Rotation.from_quat(track.quaternion[valid])
        pointing.nees[valid] = pointing_nees(
            estimate, scenario.truth[valid], track.covariance[valid]
        )
    for k in np.flatnonzero(valid):
        pointing.bound[k] = crb_sigma(scenario, k, stations[k])
    return pointing


def one_step_pointing(
    solver: OneStepSolver,
    scenario: GeoSnrScenario,
    snr: Array,
    heard: list[NDArray[np.intp]],
    lsq: Pointing,
) -> Pointing:
    """One-step SNR solver ``solver`` (e.g. the NLP, configured) on every heard station's SNR,
    each epoch started from ``lsq``'s boresight (its epoch-level estimate: one antenna, so
    the one-step solvers' observability rule, which needs two, is not applied), with
    ``lsq``'s bound.  The solver moves freely about the boresight (its variance there is
    infinite): the stored attitude is the smallest rotation taking its boresight to body
    ``+z``, as for :func:`boresight_pointing`; its NEES uses its own attitude."""
    pointing = Pointing.empty(station_counts(heard))
    for k, stations in enumerate(heard):
        if not np.isfinite(lsq.boresight[k]).all():
            pointing.reason[k] = "no least-squares start"
            continue
        epoch = scenario.epoch(k, snr[k, stations], stations)
        estimate = solver.estimate_epoch(epoch, attitude_pointing(lsq.boresight[k]))
        if estimate.failure is not None or estimate.attitude is None:
            pointing.reason[k] = estimate.failure or "no estimate"
            continue
        pointing.boresight[k] = estimate.attitude.inv().apply(BORESIGHT_BODY)
        pointing.quaternion[k] = attitude_pointing(pointing.boresight[k]).as_quat()
        pointing.sigma[k] = observable_sigma(estimate.covariance)
        pointing.bound[k] = lsq.bound[k]
        own = Rotation.from_quat(estimate.attitude.as_quat()[None])
        nees = pointing_nees(own, scenario.truth[[k]], estimate.covariance[None])
        pointing.nees[k] = nees[0]
    return pointing


def track_pointing(
    scenario: GeoSnrScenario, track: Track, n_stations: NDArray[np.intp]
) -> Pointing:
    """A filter's or smoother's track as boresights, its own sigma (also the bound), its
    yaw error with its normalised square (``yaw_nees``), its pointing NEES and its
    normalised innovations (``nis``)."""
    pointing = Pointing.empty(n_stations)
    valid = track.valid
    pointing.reason[~valid] = track.reason[~valid]
    if valid.any():
        estimate = track.attitude()
        pointing.boresight[valid] = estimate.inv().apply(BORESIGHT_BODY)
        pointing.quaternion[valid] = track.quaternion[valid]
        pointing.yaw[valid] = (estimate * scenario.truth[valid].inv()).as_rotvec()[:, 2]
        pointing.nees[valid] = pointing_nees(
            estimate, scenario.truth[valid], track.covariance[valid]
        )
    pointing.sigma = observable_sigma(track.covariance)
    pointing.bound = pointing.sigma[:, :2]
    pointing.extra["yaw_nees"] = (pointing.yaw / pointing.sigma[:, 2]) ** 2
    pointing.extra["nis"] = track.loss
    return pointing
