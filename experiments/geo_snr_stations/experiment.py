"""Experiment ``geo-snr-stations``: Garuda-1's boresight from ground-station SNRs
(Pimienta-Penalver and Crassidis).

One trial simulates the hour of :mod:`attopt.experiments.geo_snr_stations.scenario`
(SNR noise from the trial's seed) and solves it with these rows, each a registry
estimator (:data:`METHODS`; the pass ones run by
:func:`attopt.solvers.pipeline.run_estimators`):

* ``cone``: cone intersection of the three filter stations (sec. IV.B, eq. 12;
  the ``geo_cone`` estimator, :mod:`attopt.solvers.geo.boresight`);
* ``lsq``: least-squares boresight over every station that hears the satellite
  (``geo_lsq``);
* ``nlp``: the CasADi/IPOPT NLP of :mod:`attopt.solvers.snr.nlp` on every heard
  station's SNR (the paper's eq. 7 model through
  :func:`attopt.formulations.geo_link.geo_snr_epoch`), started from ``lsq``'s boresight
  (its epoch-level estimate: one antenna, so the one-step solvers' observability
  rule, which needs two, is not applied);
* ``usque``: the unscented filter of sec. V.B on the three filter stations;
* ``usque_detect``: the same with manoeuvre detection and automatic
  re-initialisation (:mod:`attopt.solvers.geo.manoeuvre`), run with and without the
  manoeuvre so that false alarms show;
* ``fg_batch``: the whole-pass factor-graph smoother (registry ``fg_batch``,
  :class:`attopt.solvers.smoother.BatchSmoother`) on the filters' SNRs, started from
  ``usque_detect`` (``usque`` would carry the manoeuvre's unmodelled rate into the
  start).

Rate input (Pimienta-Penalver and Crassidis sec. V.B: "the UKF is provided with ...
position and body rate information").  A ground observer has no gyro on the broadcaster; the
filters get the *assumed* body rate, that of the nominal slew without the
manoeuvre (:func:`assumed_rates`, noise-free), as a gyro record whose model
(:func:`rate_model`) turns the paper's "process noise ... 0.1 degree" into an
angle random walk of ``rate_arw_deg_sqrt_h`` (default 0.1 deg/h^(1/2)), a rate
random walk of ``rate_rrw_deg_h_sqrt_h`` and a 1 deg/h initial rate-error sigma.

Prior.  The paper starts its filter with 5 deg per axis.  An attitude error is
drawn with that sigma from the trial's child stream
(:func:`attopt.experiments.simulation.child_rng`) and its boresight is replaced by
``cone``'s at the first epoch (:func:`attopt.solvers.geo.manoeuvre.boresight_prior`,
yaw kept, yaw sigma 5 deg): from the raw draw (up to 9 deg off) the
stations fall outside the 9 deg main lobe at the sigma points and USQUE
never updates (measured: no update in the hour).

Error columns.  ``err_{x,y,z}_deg`` is the pointing error: the rotation vector
(true body frame) of the smallest rotation carrying the true boresight to the
estimated one (:func:`attopt.experiments.metrics.pointing_error`); its ``z``
(yaw) component is NaN: yaw about the boresight is unobservable from SNRs
(``docs/geo.md``), ``yaw_observable`` is False on every row and the filters'
own yaw error (the ``z`` component of ``estimate * truth.inv()``, which they
carry with a large sigma) is in ``yaw_err_deg``.  ``sigma_{x,y,z}_deg``: the
method's own standard deviations (NaN for ``cone``/``lsq``, and where the
method's variance is infinite: ``nlp``'s yaw); ``bound_{x,y}_deg``: the
filters' and smoother's own sigma, and for the snapshot methods the
Cramer-Rao bound of their stations' SNRs
(:func:`attopt.formulations.geo_fisher.snr_fisher_information`, pseudo-inverse: the
boresight axis is its nullspace).  ``usque_detect`` rows add the windowed
test's ``p_value`` and ``detected`` at the epochs it restarted.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from pydantic import Field
from scipy.spatial.transform import Rotation

from attopt.experiments.config import Parameters
from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.geo_snr_stations.report import report
from attopt.experiments.geo_snr_stations.scenario import (
    MANOEUVRE_START_S,
    SNR_SIGMA_DB,
    GeoSnrScenario,
    build_geo_snr_scenario,
    true_attitude,
)
from attopt.experiments.metrics import pointing_error
from attopt.experiments.simulation import GYRO_STREAM, child_rng
from attopt.formulations.errors import AttoptError
from attopt.formulations.geo_fisher import snr_fisher_information
from attopt.formulations.geo_link import BORESIGHT_BODY, attitude_pointing, geo_snr_epoch
from attopt.formulations.gyro import GyroModel, GyroSamples, mean_rates
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.filters import FilterOptions
from attopt.solvers.geo.boresight import check_elevations, estimated_boresight
from attopt.solvers.geo.manoeuvre import DetectionOptions, boresight_prior, detect_and_reinitialise
from attopt.solvers.pipeline import Run, run_estimators
from attopt.solvers.registry import estimator
from attopt.solvers.results import Track, observable_sigma

Array = NDArray[np.float64]


FILTER_STATIONS = ("Surabaya", "General Santos", "Labuan")
"""The three stations of the cone intersection and the filters: those that hear
Garuda-1 during the whole hour (``docs/geo.md``)."""
FILTER_OPTIONS = FilterOptions(gate_probability=1.0, max_attitude_sigma=np.radians(90.0))
"""No innovation gate (the paper's filter has none; :mod:`attopt.solvers.geo.manoeuvre`),
and a 90 deg validity limit: the yaw sigma is large by nature, not a failure."""
METHODS = {
    "cone": "geo_cone",
    "lsq": "geo_lsq",
    "nlp": "nlp",
    "usque": "usque",
    "fg_batch": "fg_batch",
}
"""Row label -> registry name (module docstring); ``usque_detect`` is USQUE with
manoeuvre detection (:mod:`attopt.solvers.geo.manoeuvre`)."""
PASS_METHODS = ("usque", "fg_batch")
"""The rows run on the filter pass with :data:`FILTER_OPTIONS`; ``fg_batch`` starts from
``usque_detect``."""


MIN_WINDOW = 3
"""Fewest epochs in the detection window (a 120 s window is 2 epochs at 60 s steps, where
the first epoch after the manoeuvre's start alone can miss ``false_alarm``)."""


class GeoSnrStationsParameters(Parameters):
    """Parameters of ``geo-snr-stations`` (the GEO broadcaster seen by ground stations)."""

    duration_s: float = Field(3600.0, gt=0, description="Length of the pass.")
    step_s: float = Field(10.0, gt=0, description="Time between epochs.")
    manoeuvre: list[bool] = Field(
        default_factory=lambda: [False, True],
        description="One setting per value: without and with the unmodelled manoeuvre.",
    )
    initial_sigma_deg: float = Field(5.0, gt=0, description="Per-axis sigma of the prior.")
    rate_arw_deg_sqrt_h: float = Field(
        0.1, gt=0, description="Angle random walk of the assumed-rate gyro."
    )
    rate_rrw_deg_h_sqrt_h: float = Field(
        1.0, gt=0, description="Rate random walk of the assumed-rate gyro."
    )
    detection_window_s: float = Field(
        120.0, gt=0, description="Window of the manoeuvre detector's NIS test."
    )
    false_alarm: float = Field(
        1e-6, gt=0, lt=1, description="False-alarm probability of the NIS test."
    )


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per ``manoeuvre`` value; every method runs inside each trial."""
    values = parameters["manoeuvre"]
    values = values if isinstance(values, list | tuple) else [values]
    if parameters["step_s"] <= 0 or parameters["duration_s"] < 2 * parameters["step_s"]:
        raise ValueError("need step_s > 0 and at least two epochs")
    return [{**parameters, "manoeuvre": bool(value)} for value in values]


def detection_window(setting: Mapping[str, Any]) -> int:
    """Epochs in the NIS test's window: ``detection_window_s``, at least :data:`MIN_WINDOW`."""
    return max(MIN_WINDOW, round(setting["detection_window_s"] / setting["step_s"]))


def rate_model(setting: Mapping[str, Any]) -> GyroModel:
    """The assumed-rate "gyro" (module docstring), one sample per epoch."""
    per_sqrt_s = np.radians(1.0) / 60.0
    return GyroModel(
        name="assumed_rate",
        sigma_v=setting["rate_arw_deg_sqrt_h"] * per_sqrt_s,
        sigma_u=setting["rate_rrw_deg_h_sqrt_h"] * per_sqrt_s / 3600.0,
        initial_bias_sigma=np.radians(1.0) / 3600.0,
        rate_hz=1.0 / setting["step_s"],
    )


def assumed_rates(scenario: GeoSnrScenario) -> GyroSamples:
    """Body rates of the nominal slew (no manoeuvre) at the epochs."""
    dt = float(scenario.t[1] - scenario.t[0])
    return GyroSamples(scenario.t, mean_rates(true_attitude(scenario.t), dt), dt)


def crb_sigma(scenario: GeoSnrScenario, k: int, stations: NDArray[np.intp]) -> Array:
    """Cramer-Rao standard deviations (rad) about body x, y of epoch ``k``'s ``stations``."""
    fisher = snr_fisher_information(
        scenario.truth[k],
        scenario.satellite_eci_km[k],
        scenario.stations_eci_km[k, stations],
        SNR_SIGMA_DB,
        scenario.link,
    )
    return np.sqrt(np.diag(np.linalg.pinv(fisher, rcond=1e-9, hermitian=True))[:2])


@dataclass
class Pointing:
    """One method's boresight estimates at the ``N`` epochs and what its rows report
    (module docstring): ``sigma`` ``(N, 3)`` rad, ``bound`` ``(N, 2)`` rad, the filters'
    ``yaw`` error (rad), the ``reason`` of each epoch without estimate and extra columns."""

    boresight: Array
    sigma: Array
    bound: Array
    yaw: Array
    reason: NDArray[np.object_]
    extra: dict[str, Array] = field(default_factory=dict)

    @classmethod
    def empty(cls, n: int) -> Pointing:
        return cls(
            np.full((n, 3), np.nan),
            np.full((n, 3), np.nan),
            np.full((n, 2), np.nan),
            np.full(n, np.nan),
            np.full(n, "", dtype=object),
        )

    def frame(self, label: str, scenario: GeoSnrScenario) -> pd.DataFrame:
        """The rows: pointing error, sigmas, bounds, the filters' yaw error, validity."""
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
            **self.extra,
        }
        return pd.DataFrame(columns)


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


def boresight_pointing(
    name: str, scenario: GeoSnrScenario, snr: Array, stations: list[NDArray[np.intp]]
) -> Pointing:
    """Registry boresight estimator ``name`` over the epochs, each on its ``stations``,
    with the Cramer-Rao bound of those stations' SNRs where it has an estimate."""
    snapshots, reason = station_snapshots(scenario, snr, stations)
    track = estimator(name).solve_sequence(snapshots)
    pointing = Pointing.empty(scenario.t.size)
    pointing.reason = np.where(reason != "", reason, track.reason)
    valid = track.valid
    pointing.boresight[valid] = estimated_boresight(track)[valid]
    for k in np.flatnonzero(valid):
        pointing.bound[k] = crb_sigma(scenario, k, stations[k])
    return pointing


def nlp_pointing(scenario: GeoSnrScenario, snr: Array, lsq: Pointing) -> Pointing:
    """The SNR NLP on every heard station's SNR, each epoch started from ``lsq``'s
    boresight (its epoch-level estimate, module docstring), with ``lsq``'s bound."""
    nlp = estimator(METHODS["nlp"])
    pointing = Pointing.empty(scenario.t.size)
    for k in range(scenario.t.size):
        if not np.isfinite(lsq.boresight[k]).all():
            pointing.reason[k] = "no least-squares start"
            continue
        heard = np.flatnonzero(np.isfinite(snr[k]))
        epoch = geo_snr_epoch(
            snr[k, heard],
            scenario.satellite_eci_km[k],
            scenario.stations_eci_km[k, heard],
            SNR_SIGMA_DB,
            scenario.link,
        )
        estimate = nlp.estimate_epoch(epoch, attitude_pointing(lsq.boresight[k]))
        if estimate.failure is not None or estimate.attitude is None:
            pointing.reason[k] = estimate.failure or "no estimate"
            continue
        pointing.boresight[k] = estimate.attitude.inv().apply(BORESIGHT_BODY)
        pointing.sigma[k] = observable_sigma(estimate.covariance)
        pointing.bound[k] = lsq.bound[k]
    return pointing


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
    epoch = geo_snr_epoch(
        snr[k, stations],
        scenario.satellite_eci_km[k],
        scenario.stations_eci_km[k, stations],
        SNR_SIGMA_DB,
        scenario.link,
    )
    return Snapshot.of(SnrMeasurement(epoch), t=float(scenario.t[k]))


def track_pointing(scenario: GeoSnrScenario, track: Track) -> Pointing:
    """A filter's or smoother's track as boresights, its own sigma (also the bound), its
    yaw error and its normalised innovations (``nis``)."""
    pointing = Pointing.empty(scenario.t.size)
    valid = track.valid
    pointing.reason[~valid] = track.reason[~valid]
    if valid.any():
        estimate = track.attitude()
        pointing.boresight[valid] = estimate.inv().apply(BORESIGHT_BODY)
        pointing.yaw[valid] = (estimate * scenario.truth[valid].inv()).as_rotvec()[:, 2]
    pointing.sigma = observable_sigma(track.covariance)
    pointing.bound = pointing.sigma[:, :2]
    pointing.extra["nis"] = track.loss
    return pointing


def _filter_prior(
    setting: Setting, scenario: GeoSnrScenario, rng: np.random.Generator, cone_start: Array
) -> Prior:
    """The paper's 5 deg draw with its boresight replaced by ``cone``'s (module docstring)."""
    sigma0 = np.radians(setting["initial_sigma_deg"])
    draw = Rotation.from_rotvec(sigma0 * rng.standard_normal(3)) * scenario.truth[0]
    start = DetectionOptions(yaw_sigma=sigma0, bias_sigma=rate_model(setting).initial_bias_sigma)
    return boresight_prior(draw, cone_start, np.zeros(3), start)


def filter_pass(
    setting: Setting,
    seed: np.random.SeedSequence,
    scenario: GeoSnrScenario,
    snr: Array,
    cone: Array,
) -> Pass:
    """The filter stations' SNRs with the assumed-rate gyro and the prior (module
    docstring), ``cone``: the cone intersection's boresight at the first epoch."""
    names = [station.name for station in scenario.stations]
    filter_idx = np.array([names.index(name) for name in FILTER_STATIONS])
    filter_snr = np.full_like(snr, np.nan)
    filter_snr[:, filter_idx] = snr[:, filter_idx]
    measurements = [scenario.measurement(k, row) for k, row in enumerate(filter_snr)]
    samples, model = assumed_rates(scenario), rate_model(setting)
    prior = _filter_prior(setting, scenario, child_rng(seed, GYRO_STREAM), cone)
    return Pass(
        scenario.t,
        epoch_snapshots(measurements, scenario.t),
        GyroRecord(samples.t, samples.rates, model),
        prior,
    )


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method (module docstring)."""
    scenario = build_geo_snr_scenario(
        setting["duration_s"], setting["step_s"], setting["manoeuvre"]
    )
    snr = scenario.simulate_snr(np.random.default_rng(seed))
    names = [station.name for station in scenario.stations]
    filter_idx = np.array([names.index(name) for name in FILTER_STATIONS])
    heard = [np.flatnonzero(np.isfinite(row)) for row in snr]
    cone_stations = [np.intersect1d(filter_idx, h) for h in heard]
    cone = boresight_pointing(METHODS["cone"], scenario, snr, cone_stations)
    lsq = boresight_pointing(METHODS["lsq"], scenario, snr, heard)
    nlp = nlp_pointing(scenario, snr, lsq)
    if not np.isfinite(cone.boresight[0]).all():
        raise ValueError(f"no cone intersection at the first epoch: {cone.reason[0]}")
    pass_ = filter_pass(setting, seed, scenario, snr, cone.boresight[0])
    detection = DetectionOptions(
        window=detection_window(setting), false_alarm=setting["false_alarm"]
    )
    boresight: Callable[[int], Array] = _cone_or_lsq(cone, lsq)
    began = time.perf_counter()
    detected = detect_and_reinitialise(pass_, boresight, detection, FILTER_OPTIONS)
    start = Run(detected.result, time.perf_counter() - began)
    methods = {label: estimator(METHODS[label], filter=FILTER_OPTIONS) for label in PASS_METHODS}
    runs = run_estimators(pass_, methods, starts={"fg_batch": start})
    detect = track_pointing(scenario, detected.result)
    detect.extra["p_value"] = detected.p_value
    detect.extra["detected"] = np.isin(np.arange(scenario.t.size), detected.detections)
    pointings = {
        "cone": cone,
        "lsq": lsq,
        "nlp": nlp,
        "usque": track_pointing(scenario, runs["usque"].track),
        "usque_detect": detect,
        "fg_batch": track_pointing(scenario, runs["fg_batch"].track),
    }
    return pd.concat(
        [p.frame(label, scenario) for label, p in pointings.items()], ignore_index=True
    )


def _cone_or_lsq(cone: Pointing, lsq: Pointing) -> Callable[[int], Array]:
    """Snapshot boresight of epoch ``k`` for a restart: the cones', else least squares'."""

    def boresight(k: int) -> Array:
        return cone.boresight[k] if np.isfinite(cone.boresight[k]).all() else lsq.boresight[k]

    return boresight


def summary_columns(rows: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """Per group: restarts per trial, mean first-detection delay after the manoeuvre
    start, and the filters' yaw RMS and share of epochs with the yaw error inside
    3 sigma (reported apart: yaw is unobservable)."""
    detected = rows["detected"].astype("boolean").fillna(False).astype(bool)
    yaw = rows["yaw_err_deg"]
    work = rows[[*keys, "trial_index", "t_s"]].assign(
        detected=detected,
        yaw_ms=yaw**2,
        yaw_inside=(yaw.abs() <= 3 * rows["sigma_z_deg"]).where(yaw.notna()).astype(float),
    )
    groups = work.groupby(keys, dropna=False)
    out = pd.DataFrame(
        {
            "restarts_per_trial": groups["detected"].sum() / groups["trial_index"].nunique(),
            "filter_yaw_rms_deg": np.sqrt(groups["yaw_ms"].mean()),
            "yaw_inside_3sigma": groups["yaw_inside"].mean(),
        }
    )
    after = work[work["detected"] & (work["t_s"] >= MANOEUVRE_START_S)]
    first = after.groupby([*keys, "trial_index"], dropna=False)["t_s"].min() - MANOEUVRE_START_S
    out["detection_delay_s"] = first.groupby(level=list(range(len(keys)))).mean()
    return out.reset_index()


EXPERIMENT = Experiment(
    name="geo-snr-stations",
    summary=(
        "Pimienta-Penalver and Crassidis: GEO broadcaster boresight from ground-station "
        "SNRs (cones, least squares, NLP, USQUE with manoeuvre detection, factor-graph "
        "smoother)"
    ),
    schema=GeoSnrStationsParameters,
    grid=grid,
    trial=trial,
    default_trials=4,
    quick_trials=1,
    quick_parameters={"duration_s": 3600.0, "step_s": 60.0},
    report=report,
    summary_columns=summary_columns,
)
"""The experiment (:mod:`attopt.experiments.registry` name ``geo-snr-stations``)."""
