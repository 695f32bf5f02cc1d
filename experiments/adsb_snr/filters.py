"""Gyro-aided filter rows of the ``adsb-snr`` experiment.

On the same measured SNRs as the single-frame methods, with a simulated
rate-integrating gyro (:mod:`attopt.formulations.gyro`) per entry of the
``gyros`` parameter (a preset, ``liu2023``: Liu et al. 2023 sec. 5.1 read
literally, 10 Hz; ``mems``: a MEMS-class unit; or a table of a gyro's numbers,
:class:`attopt.experiments.config.components.GyroNumbers`, labelled by its
``name``; all of one rate), the pass estimators of the registry that accept
SNRs (:func:`filter_labels`), run by :func:`attopt.solvers.pipeline.run_estimators`:

* ``mekf_paper``: Liu et al. 2023's MEKF (secs. 4.2-4.5, registry ``mekf``): the
  observation is the 3-2-1 Euler angles of the NLSE solution of each epoch
  (eqs. 41-46) with ``R = (paper_sigma_deg)^2 I`` (sec. 5.1's ``R``, read as
  degrees); epochs where the NLSE has no valid solution are propagated only.
  Its ``runtime_s`` is the filter's alone (add the NLSE's for the pipeline).
* ``<name>_snr`` (``mekf_snr``, ``usque_snr``, ``rts_snr``, ...): the registry
  estimator ``<name>`` with the received SNRs themselves as scalar
  measurements (Liu et al. 2023 sec. 6's proposed future work), through the
  threshold-truncated measurement model by default (``filter_snr_model =
  "truncated"``; ``"gaussian"`` is eq. 19's model, which integrates the
  selection bias of near-threshold messages,
  :mod:`attopt.formulations.snr_measurement`).  ``rts_snr`` is the
  multiplicative RTS backward pass over ``mekf_snr`` (its ``runtime_s``
  includes the forward MEKF).
* the factor-graph smoothers keep their registry names: ``fg_online``, the
  causal fixed-lag smoother; ``fg_batch``, the whole-pass smoother started
  from ``fg_online``'s estimates (or from ``rts_snr``'s when ``fg_online`` is
  not asked for; ``runtime_s`` includes that start); ``fg_batch_offsets``:
  ``fg_batch`` with one power-offset variable per aircraft (prior
  ``offset_prior_sigma_db``), for data simulated with
  ``traffic.power_offset_sigma_db > 0``, started from the single-frame NLP
  with that prior as its power allowance
  (:func:`attopt.experiments.adsb_snr.experiment.offsets_start`; its ``runtime_s``
  includes it); not in the default list (``docs/smoother.md``).
* ``mekf_offsets_snr``, ``usque_offsets_snr``: the MEKF and USQUE with each
  aircraft's power offset as an augmented state (prior ``offset_prior_sigma_db``;
  docs/filters.md, Transmitter power offsets); not in the default list either.

Rows of the gyro-aided methods carry ``pbound_{x,y,z}_deg`` when a factor-graph
smoother is asked for: the posterior Cramer-Rao bound of the pass
(:func:`attopt.experiments.metrics.posterior_bound_columns`, offsets not
modelled), the same for every method of that gyro; the rows of the estimators with
offsets (``fg_batch_offsets`` and the filters with offsets) carry the bound of the pass
with every aircraft's power unknown (prior ``offset_prior_sigma_db``, constant offsets:
the smoother with offsets at the truth), whether or not a smoother is asked for.

Every filter starts from the prior of
:func:`attopt.experiments.simulation.simulate_filter_inputs` (attitude error drawn
with ``initial_sigma_deg`` per axis, bias estimate 0) and works in ECI
(:mod:`attopt.experiments.simulation`); errors are reported in the orbit frame like
the single-frame rows.  The gyro of the ``i``-th entry of ``gyros`` and the
prior are drawn from child stream ``1 + i`` of the trial's seed; ``[gyro_fault]``
(:class:`attopt.experiments.config.components.GyroFault`) corrupts the samples of
every gyro the filters get, after the draws.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.parameters import AdsbScenario
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry
from attopt.experiments.config.components import GyroNumbers, gyro_model
from attopt.experiments.estimators import (
    FACTOR_GRAPH,
    configured_all,
    registered_labels,
    resolve,
)
from attopt.experiments.metrics import (
    attitude_columns,
    error_columns,
    gyro_columns,
    in_inertial_frame,
    in_orbit_frame,
    posterior_bound_columns,
    status_columns,
)
from attopt.experiments.simulation import (
    FilterInputs,
    GyroPass,
    GyroTruth,
    child_rng,
    gyro_truth,
    simulate_filter_inputs,
)
from attopt.formulations.attitude_measurement import AttitudeMeasurement, EulerAngleMeasurement
from attopt.formulations.conventions import euler321_from_attitude, orbit_frame_attitude
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.estimator import Estimator
from attopt.solvers.pipeline import Run, run_estimators
from attopt.solvers.results import Track
from attopt.solvers.smoother import single_frame_initial

if TYPE_CHECKING:
    from attopt.experiments.adsb_snr.experiment import AdsbSnrParameters

SNR_SUFFIX = "_snr"
PAPER_FILTER = "mekf_paper"
"""The row of Liu et al. 2023's MEKF on the NLSE's Euler angles."""
PAPER_SOURCE = "nlse"
"""The single-frame method whose Euler angles ``mekf_paper`` filters (Liu et al. 2023)."""
DEFAULT_FILTERS = ["mekf_paper", "mekf_snr", "usque_snr", "rts_snr", "fg_online", "fg_batch"]
"""The filter rows of a default run (``fg_batch_offsets`` is asked for with the
power-offset option: module docstring)."""
SNR_MODELS = ("truncated", "gaussian")
OFFSET_ESTIMATORS = ("fg_batch_offsets", "mekf_offsets", "usque_offsets")
"""The registry estimators with a power offset per aircraft (prior ``offset_prior_sigma_db``;
their rows' bound has the powers unknown)."""
FILTERS_WITH_OFFSETS = ("mekf_offsets", "usque_offsets")
"""The filters that carry each aircraft's offset as a state (random walk from the
aircraft model's ``antenna_walk_db``)."""


def filter_label(name: str) -> str:
    """The row label of registry estimator ``name`` on the SNRs: ``name + "_snr"``; the
    factor-graph smoothers keep their names."""
    return name if name in FACTOR_GRAPH else name + SNR_SUFFIX


def filter_labels() -> dict[str, str]:
    """Row label -> registry name of every ``filters`` entry: ``mekf_paper`` and the pass
    estimators that accept SNRs (:func:`filter_label`)."""
    return {PAPER_FILTER: "mekf", **registered_labels("pass", SnrMeasurement, filter_label)}


def filter_estimators(parameters: AdsbSnrParameters) -> dict[str, Estimator]:
    """Row label -> configured estimator of each of ``filters`` (the offsets' prior of
    ``fg_batch_offsets``, ``mekf_offsets`` and ``usque_offsets`` from
    ``offset_prior_sigma_db``, the filters' random walk from
    ``[receiver.aircraft_model]``'s ``antenna_walk_db`` when it models the antennas;
    then ``estimator_options``)."""
    offsets = {"offset_sigma": parameters.offset_prior_sigma_db}
    defaults: dict[str, dict[str, Any]] = dict.fromkeys(OFFSET_ESTIMATORS, offsets)
    model = parameters.receiver.aircraft_model
    if model is not None and model.antennas:
        walk = {**offsets, "offset_rate_sigma": model.antenna_walk_db}
        defaults |= dict.fromkeys(FILTERS_WITH_OFFSETS, walk)
    filters = resolve(parameters.filters, filter_labels(), "filters")
    return configured_all(filters, parameters.estimator_options, defaults)


def gyro_label(gyro: str | GyroNumbers | Mapping[str, Any]) -> str:
    """The ``gyro`` column of a ``gyros`` entry: the preset's name or the table's ``name``."""
    if isinstance(gyro, str):
        return gyro
    return gyro_model(dict(gyro) if isinstance(gyro, Mapping) else gyro).name


def adsb_gyro_truth(scenario: AdsbScenario, rate_hz: float) -> GyroTruth:
    """The scenario's truth at the gyro rate (cached per process)."""
    return _adsb_gyro_truth(scenario.key(), float(rate_hz))


@functools.lru_cache(maxsize=2)
def _adsb_gyro_truth(key: str, rate_hz: float) -> GyroTruth:
    scenario = AdsbScenario.model_validate_json(key)
    geometry = build_adsb_geometry(scenario)
    frames = orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms)
    return gyro_truth(geometry.t, frames, scenario.attitude.attitude, rate_hz)


def gyro_inputs(
    parameters: AdsbSnrParameters,
    seed: np.random.SeedSequence,
    index: int,
    truth: GyroTruth | None = None,
) -> FilterInputs:
    """The samples of gyro ``index`` of ``gyros`` (with ``gyro_fault``) and the filters'
    prior, from child stream ``1 + index`` of the trial's seed (module docstring);
    ``truth``: the scenario's
    (:func:`adsb_gyro_truth`) at the gyros' rate, computed when not given."""
    model = gyro_model(parameters.gyros[index])
    truth = truth or adsb_gyro_truth(parameters, model.rate_hz)
    rng = child_rng(seed, 1 + index)
    return simulate_filter_inputs(
        truth, model, rng, parameters.initial_sigma_deg, parameters.gyro_fault
    )


def paper_measurements(solution: Track, sigma_deg: float) -> list[AttitudeMeasurement | None]:
    """Euler angles of the valid single-frame solutions (Liu et al. 2023 eqs. 41-46)."""
    covariance = np.radians(sigma_deg) ** 2 * np.eye(3)
    out: list[AttitudeMeasurement | None] = [None] * len(solution)
    if solution.valid.any():
        angles = euler321_from_attitude(solution.attitude())
        for k, row in zip(np.flatnonzero(solution.valid), angles, strict=True):
            out[k] = EulerAngleMeasurement(row, covariance)
    return out


def considered_input_error(track: Track, source: Track) -> Track:
    """``track`` (``mekf_paper``'s) with the error of its input considered: at each epoch
    its attitude covariance gains the covariance of the most recent valid single-frame
    solution of ``source`` (the NLSE's, before the first none); the estimate is unchanged.

    Why: the NLSE's errors are correlated from epoch to epoch (the reception threshold's
    selection bias and the geometry change slowly: in the ``adsb-snr`` quick trial the
    roll error's autocorrelation is 0.46 at 60 s and its mean -0.8 deg), while the
    paper's MEKF takes each epoch's Euler angles as independent, so over the epochs its
    gyro bridges its covariance shrinks below the error it passes on (with a MEMS gyro, a
    share of 0.43 of its epochs beyond the chi-square(3) 1 - 1e-4 quantile).  Its
    innovations cannot show this: a filter that tracks a direct attitude measurement
    passes a slowly varying measurement error with unit gain.  A consider term (S. F.
    Schmidt 1966) for a measurement bias of covariance ``B`` adds ``S B S^T``, ``S`` the
    filter's sensitivity to it; here ``S = I`` (that unit gain) and ``B`` the input's whole
    covariance, since which part of it is white the filter cannot tell.  Considering only
    the first-order selection bias ``d d^T`` of the NLSE's widening left 0.17 of the
    MEMS epochs beyond the quantile (the bias grows to 1.8 deg, beyond its first-order
    value).  The price is a covariance that can be larger than the error (mean NEES
    below 3) where the input's errors are in fact white.
    """
    latest = np.maximum.accumulate(np.where(source.valid, np.arange(len(source)), -1))
    held = np.where((latest >= 0)[:, None, None], source.covariance[np.maximum(latest, 0)], 0.0)
    state_covariance = track.state_covariance
    if state_covariance is not None:
        state_covariance = state_covariance.copy()
        block = track.block("attitude")
        state_covariance[:, block, block] += held
    return replace(track, covariance=track.covariance + held, state_covariance=state_covariance)


def snr_measurements(epochs: list[SnrEpoch], model: str) -> list[AttitudeMeasurement | None]:
    """One :class:`SnrMeasurement` per epoch with at least one received message; the
    truncated model only for epochs with a finite reception threshold (without one, as
    from the receiver chain of :mod:`attopt.experiments.adsb_snr.sky`, the truncated
    likelihood is the Gaussian one)."""
    truncated = model == "truncated"
    return [
        SnrMeasurement(e, truncated=truncated and math.isfinite(e.threshold_db)) if e.m else None
        for e in epochs
    ]


def _rows(
    label: str,
    gyro: str,
    run: Run,
    simulated: GyroPass,
    common: Mapping[str, np.ndarray],
    true_attitude_orbit: Rotation,
) -> pd.DataFrame:
    track = in_orbit_frame(run.track, simulated.frames)
    return pd.DataFrame(
        {
            "method": label,
            "gyro": gyro,
            **common,
            **error_columns(track, true_attitude_orbit),
            **attitude_columns(track.quaternion, true_attitude_orbit),
            **gyro_columns(run.track, simulated),
            "loss": track.loss,
            "wrong_minimum": np.nan,
            "loss_from_truth": np.nan,
            **status_columns(track),
            "runtime_s": run.seconds,
        }
    )


def filter_rows(
    parameters: AdsbSnrParameters,
    seed: np.random.SeedSequence,
    epochs: list[SnrEpoch],
    nlse: Track | None,
    common: Mapping[str, np.ndarray],
    true_attitude_orbit: Rotation,
    single_frames: Run | None = None,
) -> list[pd.DataFrame]:
    """Rows of every requested filter for every gyro (module docstring; the parameters'
    gyros are validated to share one rate); ``single_frames``: the start of
    ``fg_batch_offsets`` (:func:`~attopt.experiments.adsb_snr.experiment.offsets_start`)."""
    methods = filter_estimators(parameters)
    if not methods:
        return []
    paper_filter = methods.pop(PAPER_FILTER, None)
    truth = adsb_gyro_truth(parameters, gyro_model(parameters.gyros[0]).rate_hz)
    snr = snr_measurements(epochs, parameters.filter_snr_model)
    paper = paper_measurements(nlse, parameters.paper_sigma_deg) if nlse is not None else None
    frames = []
    for index, gyro in enumerate(parameters.gyros):
        inputs = gyro_inputs(parameters, seed, index, truth)
        simulated = inputs.gyro_pass(truth, snr)
        runs: dict[str, Run] = {}
        if paper_filter is not None:
            if paper is None:
                raise ValueError(f"{PAPER_FILTER} needs the {PAPER_SOURCE} solution")
            paper_pass = inputs.gyro_pass(truth, paper).pass_
            run = run_estimators(paper_pass, {PAPER_FILTER: paper_filter})[PAPER_FILTER]
            track = considered_input_error(run.track, nlse)
            runs[PAPER_FILTER] = replace(run, track=track)
        starts = {}
        if single_frames is not None:
            inertial = in_inertial_frame(single_frames.track, simulated.frames)
            first = Run(single_frame_initial(inertial, inputs.prior), single_frames.seconds)
            starts = {k: first for k, e in methods.items() if e.name == "fg_batch_offsets"}
        runs |= run_estimators(simulated.pass_, methods, starts=starts)
        wanted = {e.name for e in methods.values()}
        bound = posterior_bound_columns(simulated) if FACTOR_GRAPH & wanted else {}
        with_offsets = (
            posterior_bound_columns(simulated, parameters.offset_prior_sigma_db)
            if set(OFFSET_ESTIMATORS) & wanted
            else {}
        )
        for label in parameters.filters:
            frame = _rows(
                label, gyro_label(gyro), runs[label], simulated, common, true_attitude_orbit
            )
            offsets = label in methods and methods[label].name in OFFSET_ESTIMATORS
            frames.append(frame.assign(**(with_offsets if offsets else bound)))
    return frames
