"""Gyro-aided filter rows of the ``adsb-snr`` experiment (issue 5).

On the same measured SNRs as the single-frame methods, with a simulated
rate-integrating gyro (:mod:`attopt.formulations.gyro`, 10 Hz) per entry of the
``gyros`` parameter (``seed000``: seed 000 sec. 5.1 read literally;
``mems``: a MEMS-class unit):

* ``mekf_paper``: seed 000's MEKF (secs. 4.2-4.5): the observation is the
  3-2-1 Euler angles of the NLSE solution of each epoch (eqs. 41-46) with
  ``R = (paper_sigma_deg)^2 I`` (sec. 5.1's ``R``, read as degrees); epochs
  where the NLSE has no valid solution are propagated only.  Its
  ``runtime_s`` is the filter's alone (add the NLSE's for the pipeline).
* ``mekf_snr``: the MEKF with the received SNRs themselves as scalar
  measurements (seed 000 sec. 6's proposed future work), through the
  threshold-truncated measurement model by default (``filter_snr_model =
  "truncated"``; ``"gaussian"`` is eq. 19's model, which integrates the
  selection bias of near-threshold messages, :mod:`attopt.formulations.snr_measurement`).
* ``usque_snr``: the USQUE unscented filter on the same SNR measurements.
* ``rts_snr``: the multiplicative RTS backward pass over ``mekf_snr`` (its
  ``runtime_s`` includes the forward MEKF).
* ``fg_online``: the causal fixed-lag factor-graph smoother
  (:class:`attopt.solvers.smoother.OnlineSmoother`) on the same SNR measurements.
* ``fg_batch``: the whole-pass factor-graph smoother
  (:class:`attopt.solvers.smoother.BatchSmoother`) started from ``fg_online``'s estimates (or
  from ``rts_snr``'s when ``fg_online`` is not asked for); ``runtime_s``
  includes that start.
* ``fg_batch_offsets``: ``fg_batch`` with one power-offset variable per
  aircraft (prior ``offset_prior_sigma_db``), for data simulated with
  ``power_offset_sigma_db > 0`` (issue 6 sec. 2).  Not in the default list:
  its cost grows with the number of aircraft in view at once (``docs/smoother.md``).

Rows of the gyro-aided methods carry ``pbound_{x,y,z}_deg`` when a ``fg_*``
row is asked for: the posterior Cramer-Rao bound of the pass
(:func:`attopt.solvers.bounds.posterior_bound`, offsets not modelled), the
same for every method of that gyro.

Every filter starts from the prior of
:func:`attopt.experiments.filtering.simulate_filter_inputs` (attitude error drawn
with ``initial_sigma_deg`` per axis, bias estimate 0) and works in ECI
(:mod:`attopt.experiments.filtering`); errors are reported in the orbit frame like
the single-frame rows.  The gyro of the ``i``-th entry of ``gyros`` and the
prior are drawn from child stream ``1 + i`` of the trial's seed.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from attopt.experiments.adsb_snr.scenario import build_adsb_geometry, true_attitude
from attopt.experiments.filtering import (
    FilterInputs,
    GyroTruth,
    bound_columns,
    child_rng,
    filter_columns,
    gyro_truth,
    in_orbit_frame,
    method_name,
    run_filter,
    run_filters,
    simulate_filter_inputs,
)
from attopt.experiments.metrics import error_columns
from attopt.formulations.attitude_measurement import AttitudeMeasurement, EulerAngleMeasurement
from attopt.formulations.conventions import euler321_from_attitude, orbit_frame_attitude
from attopt.formulations.gyro import GYRO_MODELS
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.results import Track

SNR_SUFFIX = "_snr"
FILTER_METHODS = {
    "mekf_paper": "mekf",
    "mekf_snr": "mekf",
    "usque_snr": "usque",
    "rts_snr": "rts",
    "fg_online": "fg_online",
    "fg_batch": "fg_batch",
    "fg_batch_offsets": "fg_batch_offsets",
}
"""Filter rows and the filter kind each runs."""
DEFAULT_FILTERS = ["mekf_paper", "mekf_snr", "usque_snr", "rts_snr", "fg_online", "fg_batch"]
"""The filter rows of a default run (``fg_batch_offsets`` is asked for with the
power-offset option: module docstring)."""
SNR_MODELS = ("truncated", "gaussian")
PAPER_SOURCE = "nlse"
"""The single-frame method whose Euler angles ``mekf_paper`` filters (seed 000)."""


def check_parameters(parameters: Mapping[str, Any]) -> None:
    """Raise ValueError on unknown filter methods, gyro models or SNR models."""
    unknown = sorted(set(parameters["filters"]) - set(FILTER_METHODS))
    if unknown:
        raise ValueError(f"unknown filters {unknown}; known: {sorted(FILTER_METHODS)}")
    gyros = sorted(set(parameters["gyros"]) - set(GYRO_MODELS))
    if gyros:
        raise ValueError(f"unknown gyros {gyros}; known: {sorted(GYRO_MODELS)}")
    if parameters["filter_snr_model"] not in SNR_MODELS:
        raise ValueError(f"filter_snr_model must be one of {SNR_MODELS}")


@functools.lru_cache(maxsize=2)
def adsb_gyro_truth(
    duration_s: float, step_s: float, n_aircraft: int, traffic_seed: int, rate_hz: float
) -> GyroTruth:
    """The scenario's truth at the gyro rate (cached per process)."""
    geometry = build_adsb_geometry(duration_s, step_s, n_aircraft, traffic_seed)
    frames = orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms)
    return gyro_truth(geometry.t, frames, true_attitude, rate_hz)


def paper_measurements(solution: Track, sigma_deg: float) -> list[AttitudeMeasurement | None]:
    """Euler angles of the valid single-frame solutions (seed 000 eqs. 41-46)."""
    covariance = np.radians(sigma_deg) ** 2 * np.eye(3)
    out: list[AttitudeMeasurement | None] = [None] * len(solution)
    if solution.valid.any():
        angles = euler321_from_attitude(solution.attitude())
        for k, row in zip(np.flatnonzero(solution.valid), angles, strict=True):
            out[k] = EulerAngleMeasurement(row, covariance)
    return out


def snr_measurements(epochs: list[SnrEpoch], model: str) -> list[AttitudeMeasurement | None]:
    """One :class:`SnrMeasurement` per epoch with at least one received message."""
    truncated = model == "truncated"
    return [SnrMeasurement(e, truncated=truncated) if e.m else None for e in epochs]


def _rows(
    method: str,
    gyro: str,
    result: Track,
    seconds: float,
    inputs: FilterInputs,
    truth: GyroTruth,
    common: Mapping[str, np.ndarray],
    true_attitude_orbit: Any,
) -> pd.DataFrame:
    solution = in_orbit_frame(result, truth.epoch_frames)
    return pd.DataFrame(
        {
            "method": method,
            "gyro": gyro,
            **common,
            **error_columns(solution, true_attitude_orbit),
            **filter_columns(result, inputs, truth),
            "loss": solution.loss,
            "wrong_minimum": np.nan,
            "loss_from_truth": np.nan,
            "valid": solution.valid,
            "reason": solution.reason.astype(str),
            "runtime_s": seconds,
        }
    )


def filter_rows(
    setting: Mapping[str, Any],
    seed: np.random.SeedSequence,
    epochs: list[SnrEpoch],
    nlse: Track | None,
    common: Mapping[str, np.ndarray],
    true_attitude_orbit: Any,
) -> list[pd.DataFrame]:
    """Rows of every requested filter for every gyro model (module docstring)."""
    wanted = list(setting["filters"])
    if not wanted:
        return []
    truth = adsb_gyro_truth(
        setting["duration_s"],
        setting["step_s"],
        setting["n_aircraft"],
        setting["traffic_seed"],
        GYRO_MODELS[setting["gyros"][0]].rate_hz,
    )
    snr = snr_measurements(epochs, setting["filter_snr_model"])
    paper = paper_measurements(nlse, setting["paper_sigma_deg"]) if nlse is not None else None
    frames = []
    for index, gyro in enumerate(setting["gyros"]):
        model = GYRO_MODELS[gyro]
        if model.rate_hz != GYRO_MODELS[setting["gyros"][0]].rate_hz:
            raise ValueError("every gyro of a setting must have the same rate")
        rng = child_rng(seed, 1 + index)
        inputs = simulate_filter_inputs(truth, model, rng, setting["initial_sigma_deg"])
        runs: dict[str, tuple[Track, float]] = {}
        if "mekf_paper" in wanted:
            if paper is None:
                raise ValueError(f"mekf_paper needs the {PAPER_SOURCE} solution")
            runs["mekf_paper"] = run_filter("mekf", inputs, truth, paper, "mekf_paper")
        kinds = [FILTER_METHODS[m] for m in wanted if m != "mekf_paper"]
        for kind, run in run_filters(
            kinds, inputs, truth, snr, SNR_SUFFIX, setting["offset_prior_sigma_db"]
        ).items():
            runs[method_name(kind, SNR_SUFFIX)] = run
        bound = bound_columns(runs, inputs, truth, snr)
        for method in wanted:
            result, seconds = runs[method]
            frame = _rows(method, gyro, result, seconds, inputs, truth, common, true_attitude_orbit)
            frames.append(frame.assign(**bound))
    return frames
