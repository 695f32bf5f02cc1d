"""Experiment ``geo-snr-stations``: a GEO broadcaster's boresight from ground-station SNRs
(Pimienta-Penalver and Crassidis).

One trial simulates the pass of :mod:`attopt.experiments.geo_snr_stations.scenario`
(the world of :class:`~attopt.experiments.geo_snr_stations.parameters.GeoWorld`; SNR
noise from the trial's seed) and solves it with the rows of ``methods`` (snapshot
estimators, :func:`method_labels`) and ``filters`` (pass estimators,
:func:`filter_labels`; run by :func:`attopt.solvers.pipeline.run_estimators`), each a
registry estimator.  The defaults:

* ``cone``: cone intersection of the filter stations (``filter_stations``; sec. IV.B,
  eq. 12; the ``geo_cone`` estimator, :mod:`attopt.solvers.geo.boresight`);
* ``lsq``: least-squares boresight over every station that hears the satellite
  (``geo_lsq``);
* ``nlp``: the CasADi/IPOPT NLP of :mod:`attopt.solvers.snr.nlp` on every heard
  station's SNR (the paper's eq. 7 model through
  :func:`attopt.formulations.geo_link.geo_snr_epoch`), started from ``lsq``'s boresight
  (any one-step SNR solver of the registry runs so);
* ``usque``: the unscented filter of sec. V.B on the filter stations;
* ``usque_detect``: the same with manoeuvre detection and automatic
  re-initialisation (:mod:`attopt.solvers.geo.manoeuvre`), run with and without the
  manoeuvre so that false alarms show;
* ``fg_batch``: the whole-pass factor-graph smoother (registry ``fg_batch``,
  :class:`attopt.solvers.smoother.BatchSmoother`) on the filters' SNRs, started from
  ``usque_detect`` (``usque`` would carry the manoeuvre's unmodelled rate into the
  start); so does every batch smoother.  Other pass estimators start as their
  ``starts_from`` says, from an estimator with the filters' options (:func:`configured`).
  One that cannot run on this pass (no rigid-body dynamics, no transmitter sources)
  gives invalid rows with the reason.

The filters' options: no innovation gate (the paper's filter has none;
:mod:`attopt.solvers.geo.manoeuvre`) and a 90 deg validity limit (:data:`FILTER_OPTIONS`).

Rate input (Pimienta-Penalver and Crassidis sec. V.B: "the UKF is provided with ...
position and body rate information").  A ground observer has no gyro on the broadcaster; the
filters get the *assumed* body rate, that of the nominal slew without the
manoeuvre (:func:`assumed_rates`, noise-free), as a gyro record whose model
(:func:`rate_model`, ``[assumed_rate]``) turns the paper's "process noise ... 0.1 degree"
into an angle random walk of ``arw_deg_sqrt_h`` (0.1 deg/h^(1/2)), a rate random walk of
``rrw_deg_h_sqrt_h`` (1 deg/h per h^(1/2)) and an initial rate-error sigma of
``initial_sigma_deg_h`` (1 deg/h).

Prior (:func:`filter_prior`).  The paper starts its filter with 5 deg per axis
(``initial_sigma_deg``).  An attitude error is drawn with that sigma from the trial's
child stream (:func:`attopt.experiments.simulation.child_rng`) and its boresight is
replaced by ``cone``'s at the first epoch
(:func:`attopt.solvers.geo.manoeuvre.boresight_prior`, yaw kept, yaw sigma
``initial_sigma_deg``, sigma across it ``[restart]``'s ``boresight_sigma_deg``): from
the raw draw (up to 9 deg off) the
stations fall outside the 9 deg main lobe at the sigma points and USQUE
never updates (measured: no update in the hour).  Restarts after a detection use
``[restart]`` (:func:`detection_options`).

Columns. ``err_{x,y,z}_deg`` is the pointing error: the rotation vector (true body
frame) of the smallest rotation carrying the true boresight to the estimated one
(:func:`attopt.experiments.metrics.pointing_error`); its ``z`` (yaw) component is NaN:
yaw about the boresight is unobservable from SNRs (``docs/geo.md``), ``yaw_observable``
is False on every row and the filters' own yaw error (the ``z`` component of ``estimate
* truth.inv()``, which they carry with a large sigma) is in ``yaw_err_deg``.
``sigma_{x,y,z}_deg``: the method's own standard deviations (NaN for ``cone``/``lsq``,
and where the method's variance is infinite: ``nlp``'s yaw); ``bound_{x,y}_deg``: the
filters' and smoother's own sigma, and for the snapshot methods the Cramer-Rao bound of
their stations' SNRs (:func:`attopt.formulations.geo_fisher.snr_fisher_information`,
pseudo-inverse: the boresight axis is its nullspace). ``q_est_{x,y,z,w}``: the estimated
attitude (ECI -> body, scipy scalar-last; NaN where invalid); for ``cone``, ``lsq`` and
the one-step solvers, which estimate the boresight only, it is the smallest rotation
carrying the estimated boresight to body ``+z``
(:func:`attopt.formulations.geo_link.attitude_pointing`): its yaw about the boresight is
this convention, not an estimate, and only its boresight ``q_est^-1 z`` means something
(the filters' yaw is an estimate, weakly observed). ``q_true_*``: the true attitude.
``nees``: against the method's own covariance, over the two axes across the boresight
(:func:`~attopt.experiments.geo_snr_stations.pointing.pointing_nees`, ``nees_dof`` 2),
the axes the SNRs see, for every method: the one-step solvers' yaw variance is
infinite, and the filters' yaw comes from the prior carried by the assumed rates, which
no SNR checks; the filters' ``yaw_nees`` (``yaw_err^2 / sigma_z^2``, 1 dof) is kept for
the record. ``n_stations``: the stations whose
SNRs the method was given at the epoch. ``usque_detect`` rows add the windowed test's
``p_value``, ``detected`` at the epochs it restarted and ``since_manoeuvre_s`` (time
from the manoeuvre's start, negative before it); the filters' rows their normalised
innovations ``nis``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from pydantic import Field, ValidationInfo, field_validator
from scipy.spatial.transform import Rotation

from attopt.experiments.config import Parameters
from attopt.experiments.estimators import (
    FACTOR_GRAPH,
    EstimatorOptions,
    Options,
    label_field,
    registered_labels,
    resolve,
)
from attopt.experiments.estimators import configured as configured_estimator
from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.geo_snr_stations.parameters import GeoWorld
from attopt.experiments.geo_snr_stations.pointing import (
    Pointing,
    boresight_pointing,
    one_step_pointing,
    track_pointing,
)
from attopt.experiments.geo_snr_stations.report import report
from attopt.experiments.geo_snr_stations.scenario import GeoSnrScenario, build_geo_snr_scenario
from attopt.experiments.simulation import GYRO_STREAM, child_rng
from attopt.formulations.errors import AttoptError
from attopt.formulations.gyro import GyroModel, GyroSamples, mean_rates
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.estimator import Estimator
from attopt.solvers.filters import FilterOptions
from attopt.solvers.geo.boresight import BoresightEstimator
from attopt.solvers.geo.manoeuvre import DetectionOptions, boresight_prior, detect_and_reinitialise
from attopt.solvers.pipeline import Run, run_estimators
from attopt.solvers.registry import estimator, estimators
from attopt.solvers.snr.one_step import OneStepSolver

Array = NDArray[np.float64]

FILTER_OPTIONS = FilterOptions(gate_probability=1.0, max_attitude_sigma=np.radians(90.0))
"""No innovation gate (the paper's filter has none; :mod:`attopt.solvers.geo.manoeuvre`),
and a 90 deg validity limit: the yaw sigma is large by nature, not a failure."""
DETECT = "usque_detect"
"""The row label of USQUE with manoeuvre detection and restart
(:func:`attopt.solvers.geo.manoeuvre.detect_and_reinitialise`)."""
MIN_WINDOW = 3
"""Fewest epochs in the detection window (a 120 s window is 2 epochs at 60 s steps, where
the first epoch after the manoeuvre's start alone can miss ``false_alarm``)."""


def method_labels() -> dict[str, str]:
    """Row label -> registry name of the ``methods``: the GEO boresight estimators without
    their ``geo_`` prefix (``cone``, ``lsq``) and the one-step SNR solvers by name."""
    labels = {}
    for name in estimators("snapshot", SnrMeasurement):
        found = estimator(name)
        if isinstance(found, BoresightEstimator):
            labels[name.removeprefix("geo_")] = name
        elif isinstance(found, OneStepSolver):
            labels[name] = name
    return labels


def filter_labels() -> dict[str, str]:
    """Row label -> registry name of the ``filters``: :data:`DETECT` (USQUE with manoeuvre
    detection) and the pass estimators that accept SNRs, by name."""
    return {DETECT: "usque", **registered_labels("pass", SnrMeasurement)}


class AssumedRate(Parameters):
    """The filters' assumed-rate "gyro": the nominal slew's body rate, one sample per
    epoch, with this noise model (module docstring)."""

    arw_deg_sqrt_h: float = Field(
        0.1, gt=0, description="Angle random walk (the paper's 0.1 deg process noise)."
    )
    rrw_deg_h_sqrt_h: float = Field(1.0, gt=0, description="Rate random walk.")
    initial_sigma_deg_h: float = Field(
        1.0, gt=0, description="Initial rate-error (bias) sigma per axis."
    )


class Restart(Parameters):
    """The filter's re-initialisation at a detected manoeuvre
    (:class:`attopt.solvers.geo.manoeuvre.DetectionOptions`)."""

    boresight_sigma_deg: float = Field(
        0.02,
        gt=0,
        description="Prior sigma across the snapshot boresight (also the first prior's).",
    )
    yaw_sigma_deg: float = Field(20.0, gt=0, description="Prior sigma about the boresight.")
    rate_sigma_deg_h: float = Field(
        20.0, gt=0, description="Prior sigma of the rate error (bias) per axis."
    )
    max_restarts: int = Field(3, ge=0, description="Most re-initialisations per pass.")


class GeoSnrStationsParameters(GeoWorld):
    """Parameters of ``geo-snr-stations``: the simulated world (:class:`GeoWorld`), the
    settings and the estimators."""

    manoeuvre: list[bool] = Field(
        default_factory=lambda: [False, True],
        min_length=1,
        description="One setting per value: without and with the unmodelled manoeuvre.",
    )
    initial_sigma_deg: float = Field(5.0, gt=0, description="Per-axis sigma of the prior.")
    detection_window_s: float = Field(
        120.0, gt=0, description="Window of the manoeuvre detector's NIS test."
    )
    false_alarm: float = Field(
        1e-6, gt=0, lt=1, description="False-alarm probability of the NIS test."
    )
    methods: list[label_field(method_labels, "methods")] = Field(
        default_factory=lambda: ["cone", "lsq", "nlp"],
        description="Snapshot estimators (row labels: cone, lsq, one-step SNR solvers).",
    )
    filters: list[label_field(filter_labels, "filters")] = Field(
        default_factory=lambda: ["usque", DETECT, "fg_batch"],
        description="Filters and smoothers (registry names, and usque_detect).",
    )
    filter_stations: list[str] = Field(
        default_factory=lambda: ["Surabaya", "General Santos", "Labuan"],
        min_length=3,
        description="Stations of the cone intersection and the filters (they hear all pass).",
    )
    assumed_rate: AssumedRate = Field(
        default_factory=AssumedRate, description="The filters' assumed-rate gyro."
    )
    restart: Restart = Field(default_factory=Restart, description="Restart after a detection.")
    estimator_options: EstimatorOptions

    @field_validator("filters")
    @classmethod
    def _labels(cls, value: list[str], info: ValidationInfo) -> list[str]:
        methods = info.data.get("methods")
        if methods is None:
            return value
        labels = [*methods, *value]
        repeated = sorted({label for label in labels if labels.count(label) > 1})
        if repeated:
            raise ValueError(f"row labels must be unique across methods and filters: {repeated}")
        if not labels:
            raise ValueError("need at least one of methods and filters")
        return value

    @field_validator("filter_stations")
    @classmethod
    def _stations(cls, value: list[str], info: ValidationInfo) -> list[str]:
        repeated = sorted({name for name in value if value.count(name) > 1})
        if repeated:
            raise ValueError(f"filter stations must be unique: {repeated}")
        stations = info.data.get("stations")
        names = [station.name for station in stations or ()]
        unknown = [name for name in value if name not in names]
        if stations is not None and unknown:
            raise ValueError(f"{unknown} are not stations; stations: {names}")
        return value


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per ``manoeuvre`` value; every method runs inside each trial."""
    return [{**parameters, "manoeuvre": value} for value in parameters["manoeuvre"]]


def setting_parameters(setting: Setting) -> GeoSnrStationsParameters:
    """The validated parameters of one setting (its single ``manoeuvre`` value as a list)."""
    return GeoSnrStationsParameters.model_validate({**setting, "manoeuvre": [setting["manoeuvre"]]})


def detection_window(parameters: GeoSnrStationsParameters) -> int:
    """Epochs in the NIS test's window: ``detection_window_s``, at least :data:`MIN_WINDOW`."""
    return max(MIN_WINDOW, round(parameters.detection_window_s / parameters.step_s))


def detection_options(parameters: GeoSnrStationsParameters) -> DetectionOptions:
    """The detector's test (``detection_window_s``, ``false_alarm``) and restart
    (``[restart]``)."""
    restart = parameters.restart
    return DetectionOptions(
        window=detection_window(parameters),
        false_alarm=parameters.false_alarm,
        boresight_sigma=np.radians(restart.boresight_sigma_deg),
        yaw_sigma=np.radians(restart.yaw_sigma_deg),
        bias_sigma=np.radians(restart.rate_sigma_deg_h) / 3600.0,
        max_restarts=restart.max_restarts,
    )


def rate_model(parameters: GeoSnrStationsParameters) -> GyroModel:
    """The assumed-rate "gyro" (module docstring), one sample per epoch."""
    rate = parameters.assumed_rate
    per_sqrt_s = np.radians(1.0) / 60.0
    return GyroModel(
        name="assumed_rate",
        sigma_v=rate.arw_deg_sqrt_h * per_sqrt_s,
        sigma_u=rate.rrw_deg_h_sqrt_h * per_sqrt_s / 3600.0,
        initial_bias_sigma=np.radians(rate.initial_sigma_deg_h) / 3600.0,
        rate_hz=1.0 / parameters.step_s,
    )


def assumed_rates(scenario: GeoSnrScenario) -> GyroSamples:
    """Body rates of the nominal slew (no manoeuvre) at the epochs."""
    dt = float(scenario.t[1] - scenario.t[0])
    return GyroSamples(scenario.t, mean_rates(scenario.nominal, dt), dt)


def configured(name: str, options: Options | None = None) -> Estimator:
    """Registry estimator ``name`` with :data:`FILTER_OPTIONS` where it has filter options,
    then ``options``' table for it (``estimator_options``,
    :func:`attopt.experiments.estimators.configured`)."""
    has_filter = "filter" in {f.name for f in dataclasses.fields(estimator(name))}
    defaults = {"filter": FILTER_OPTIONS} if has_filter else {}
    return configured_estimator(name, options or {}, **defaults)


def filter_prior(
    parameters: GeoSnrStationsParameters,
    seed: np.random.SeedSequence,
    scenario: GeoSnrScenario,
    cone_start: Array,
) -> Prior:
    """The gyro-aided filters' prior at the first epoch (ECI -> body; module docstring).

    Pimienta-Penalver and Crassidis start their filter with ``initial_sigma_deg`` (5 deg)
    per axis: an attitude error of that sigma is drawn from trial ``seed``'s child stream
    (:func:`attopt.experiments.simulation.child_rng`, :data:`GYRO_STREAM`) about the true
    first attitude, and its boresight is replaced by ``cone_start``, the cone
    intersection's boresight at the first epoch (ECI;
    :func:`attopt.solvers.geo.manoeuvre.boresight_prior`): the yaw of the draw is kept with
    sigma ``initial_sigma_deg``, the sigma across the boresight is ``[restart]``'s
    ``boresight_sigma_deg``, the rate error (bias) starts at zero with the assumed-rate
    model's initial sigma (:func:`rate_model`).  The trial's filters
    (:func:`filter_pass`) and its export
    (:func:`attopt.experiments.geo_snr_stations.export.export`) both start from it.
    """
    sigma0 = np.radians(parameters.initial_sigma_deg)
    rng = child_rng(seed, GYRO_STREAM)
    draw = Rotation.from_rotvec(sigma0 * rng.standard_normal(3)) * scenario.truth[0]
    start = DetectionOptions(
        boresight_sigma=np.radians(parameters.restart.boresight_sigma_deg),
        yaw_sigma=sigma0,
        bias_sigma=rate_model(parameters).initial_bias_sigma,
    )
    return boresight_prior(draw, cone_start, np.zeros(3), start)


def filter_gyro(parameters: GeoSnrStationsParameters, scenario: GeoSnrScenario) -> GyroRecord:
    """The filters' assumed-rate gyro record: :func:`assumed_rates` with :func:`rate_model`."""
    samples = assumed_rates(scenario)
    return GyroRecord(samples.t, samples.rates, rate_model(parameters))


def filter_station_indices(
    parameters: GeoSnrStationsParameters, scenario: GeoSnrScenario
) -> NDArray[np.intp]:
    """Indices of ``filter_stations`` among the scenario's stations, in their order."""
    names = scenario.station_names
    return np.array([names.index(name) for name in parameters.filter_stations], dtype=np.intp)


def filter_snrs(snr: Array, stations: NDArray[np.intp]) -> Array:
    """The measured SNRs ``snr`` ``(N, m)`` of the filter ``stations`` only (NaN at the
    others): what the filters are given."""
    filter_snr = np.full_like(snr, np.nan)
    filter_snr[:, stations] = snr[:, stations]
    return filter_snr


def filter_measurements(scenario: GeoSnrScenario, filter_snr: Array) -> list[SnrMeasurement | None]:
    """Per epoch, the finite SNRs of ``filter_snr`` (:func:`filter_snrs`) as one
    measurement (ECI -> body, :meth:`GeoSnrScenario.measurement`), ``None`` where there
    are none."""
    return [
        scenario.measurement(k, row) if np.isfinite(row).any() else None
        for k, row in enumerate(filter_snr)
    ]


def cone_start(cone: Pointing) -> Array:
    """``cone``'s boresight at the first epoch (ECI), the filters' prior boresight.

    Raises:
        ValueError: the cones do not intersect at the first epoch.
    """
    if not np.isfinite(cone.boresight[0]).all():
        raise ValueError(f"no cone intersection at the first epoch: {cone.reason[0]}")
    return cone.boresight[0]


def filter_pass(
    parameters: GeoSnrStationsParameters,
    seed: np.random.SeedSequence,
    scenario: GeoSnrScenario,
    filter_snr: Array,
    cone: Array,
) -> Pass:
    """The filter stations' SNRs ``filter_snr`` (NaN at the others) with the assumed-rate
    gyro and the prior (module docstring), ``cone``: the cone intersection's boresight at
    the first epoch."""
    return Pass(
        scenario.t,
        epoch_snapshots(filter_measurements(scenario, filter_snr), scenario.t),
        filter_gyro(parameters, scenario),
        filter_prior(parameters, seed, scenario, cone),
    )


def pass_run(
    pass_: Pass, label: str, name: str, detected: Run | None, options: Options | None = None
) -> Run:
    """Registry pass estimator ``name`` on ``pass_`` (:func:`configured` with ``options``);
    a batch smoother starts from ``detected`` (the detecting USQUE's run), another
    estimator that starts from a track from the first of its ``starts_from``, configured."""
    chosen = configured(name, options)
    starts_from = getattr(chosen, "starts_from", ())
    if name in FACTOR_GRAPH and starts_from:
        return run_estimators(pass_, {label: chosen}, starts={label: detected})[label]
    start = {f"{label} start": configured(starts_from[0], options)} if starts_from else {}
    return run_estimators(pass_, {**start, label: chosen})[label]


def filter_pointings(
    parameters: GeoSnrStationsParameters,
    seed: np.random.SeedSequence,
    scenario: GeoSnrScenario,
    snr: Array,
    snapshot: tuple[Pointing, Pointing],
) -> dict[str, Pointing]:
    """The ``filters``' rows on the filter stations' SNRs (module docstring); ``snapshot``:
    ``cone`` and ``lsq``, for the prior and the restarts."""
    cone, lsq = snapshot
    start = cone_start(cone)
    filter_snr = filter_snrs(snr, filter_station_indices(parameters, scenario))
    n_stations = np.isfinite(filter_snr).sum(axis=1)
    pass_ = filter_pass(parameters, seed, scenario, filter_snr, start)
    filters = resolve(parameters.filters, filter_labels(), "filters")
    options = parameters.estimator_options
    needs_detection = DETECT in filters or any(
        name in FACTOR_GRAPH and configured(name).starts_from for name in filters.values()
    )
    detection, detected = None, None
    if needs_detection:
        boresight: Callable[[int], Array] = _cone_or_lsq(cone, lsq)
        began = time.perf_counter()
        detection = detect_and_reinitialise(
            pass_, boresight, detection_options(parameters), configured("usque", options).filter
        )
        detected = Run(detection.result, time.perf_counter() - began)
    pointings = {}
    for label, name in filters.items():
        if detection is not None and label == DETECT:
            pointing = track_pointing(scenario, detection.result, n_stations)
            pointing.extra["p_value"] = detection.p_value
            pointing.extra["detected"] = np.isin(np.arange(scenario.t.size), detection.detections)
            pointing.extra["since_manoeuvre_s"] = scenario.t - parameters.attitude.manoeuvre.start_s
        else:
            try:
                track = pass_run(pass_, label, name, detected, options).track
            except AttoptError as error:
                pointing = Pointing.failed(n_stations, f"{type(error).__name__}: {error}")
            else:
                pointing = track_pointing(scenario, track, n_stations)
        pointings[label] = pointing
    return pointings


def simulate(
    setting: Setting, seed: np.random.SeedSequence
) -> tuple[GeoSnrStationsParameters, GeoSnrScenario, Array]:
    """The validated parameters of ``setting``, its scenario (with or without the
    manoeuvre) and trial ``seed``'s measured SNRs ``(N, m)``
    (:meth:`~attopt.experiments.geo_snr_stations.scenario.GeoSnrScenario.simulate_snr`)."""
    parameters = setting_parameters(setting)
    scenario = build_geo_snr_scenario(parameters, setting["manoeuvre"])
    return parameters, scenario, scenario.simulate_snr(np.random.default_rng(seed))


def heard_stations(snr: Array) -> list[NDArray[np.intp]]:
    """Per epoch, the indices of the stations with a measured SNR (they hear the
    satellite)."""
    return [np.flatnonzero(np.isfinite(row)) for row in snr]


def cone_pointing(
    parameters: GeoSnrStationsParameters, scenario: GeoSnrScenario, snr: Array
) -> Pointing:
    """``cone`` at every epoch: the ``geo_cone`` estimator on the filter stations that
    hear the satellite then (module docstring)."""
    stations = filter_station_indices(parameters, scenario)
    cones = [np.intersect1d(stations, heard) for heard in heard_stations(snr)]
    return boresight_pointing("geo_cone", scenario, snr, cones)


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method and filter of the setting (module docstring)."""
    parameters, scenario, snr = simulate(setting, seed)
    heard = heard_stations(snr)
    snapshot = {
        "geo_cone": cone_pointing(parameters, scenario, snr),
        "geo_lsq": boresight_pointing("geo_lsq", scenario, snr, heard),
    }
    pointings = {
        label: snapshot[name]
        if name in snapshot
        else one_step_pointing(
            configured(name, parameters.estimator_options),
            scenario,
            snr,
            heard,
            snapshot["geo_lsq"],
        )
        for label, name in resolve(parameters.methods, method_labels(), "methods").items()
    }
    if parameters.filters:
        pointings |= filter_pointings(
            parameters, seed, scenario, snr, (snapshot["geo_cone"], snapshot["geo_lsq"])
        )
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
    work = rows[[*keys, "trial_index", "since_manoeuvre_s"]].assign(
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
    after = work[work["detected"] & (work["since_manoeuvre_s"] >= 0.0)]
    first = after.groupby([*keys, "trial_index"], dropna=False)["since_manoeuvre_s"].min()
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
    compiled_loops=("filters", "smoother"),
)
"""The experiment (:mod:`attopt.experiments.registry` name ``geo-snr-stations``)."""
