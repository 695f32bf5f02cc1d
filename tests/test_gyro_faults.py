"""Gyro faults (``[gyro_fault]``): a scale-factor error, an axis stuck at a constant and a
time-tag offset change the measured samples the estimators get, and only in the stated
way; without one the record is the draw itself, bit for bit; and the estimators' epochs
stay honest under each (no valid epoch whose NEES exceeds the chi-square(3) 1 - 1e-4
quantile beyond a share of 1e-3, the fault's inconsistent epochs flagged).

The integrity passes are ``wahba-mag-sun`` windows of a few hundred seconds in sunlight
(magnetometer and Sun sensor, MEMS gyro), started 200 s into the default pass.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters, starter_toml
from attopt.experiments.config.components import (
    GyroFault,
    ScaleFactorFault,
    StuckAxisFault,
    TimeOffsetFault,
)
from attopt.experiments.reporting.statistics import nees_threshold
from attopt.experiments.simulation import GYRO_STREAM, child_rng, simulate_filter_inputs
from attopt.experiments.wahba_mag_sun.experiment import (
    EXPERIMENT,
    filter_inputs,
    filter_truth,
    trial,
)
from attopt.formulations.gyro import MEMS_GYRO, mean_rates, simulate_gyro
from attopt.formulations.passes import GyroRecord
from attopt.solvers.gyro_timeline import gyro_timeline

SEED = np.random.SeedSequence(0, spawn_key=(0, 0))
"""The seed of trial 0 of setting 0 (the sweep runner's)."""
T = np.arange(0.0, 20.0 + 1e-9, MEMS_GYRO.dt)
TUMBLE = Rotation.from_rotvec(-np.outer(T, [0.002, -0.004, 0.003]) - np.outer(T**2, [0, 0, 1e-4]))
"""A slow tumble with an accelerating z rate, 20 s at the MEMS gyro's 10 Hz."""
runner = CliRunner()


def _gyro(seed: int):
    return simulate_gyro(T, TUMBLE, MEMS_GYRO, np.random.default_rng(seed))


seeds = st.integers(0, 2**32 - 1)


# --- the samples ------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(seeds, st.lists(st.floats(-0.2, 0.2), min_size=3, max_size=3))
def test_a_scale_factor_scales_the_true_rates_with_the_same_draws(seed, error):
    """``(1 + s) omega_bar + (beta_j + beta_{j+1}) / 2 + white noise``, the draws of
    :func:`simulate_gyro` in its order (initial bias, bias steps, rate noise)."""
    gyro = _gyro(seed)
    measured = GyroFault(scale_factor=ScaleFactorFault(error=error)).measured(gyro)
    rng = np.random.default_rng(seed)
    dt, n = MEMS_GYRO.dt, T.size
    initial = MEMS_GYRO.initial_bias_sigma * rng.standard_normal(3)
    steps = MEMS_GYRO.sigma_u * np.sqrt(dt) * rng.standard_normal((n - 1, 3))
    bias = initial + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    white = np.sqrt(MEMS_GYRO.sigma_v**2 / dt + MEMS_GYRO.sigma_u**2 * dt / 12.0)
    noise = white * rng.standard_normal((n - 1, 3))
    scaled = (1.0 + np.asarray(error)) * mean_rates(TUMBLE, dt)
    np.testing.assert_allclose(
        measured.rates, scaled + 0.5 * (bias[:-1] + bias[1:]) + noise, rtol=0, atol=1e-15
    )
    assert np.array_equal(measured.t, gyro.samples.t)


def test_one_scale_factor_applies_to_every_axis():
    gyro = _gyro(1)
    one = GyroFault(scale_factor=ScaleFactorFault(error=0.01)).measured(gyro)
    three = GyroFault(scale_factor=ScaleFactorFault(error=[0.01] * 3)).measured(gyro)
    assert np.array_equal(one.rates, three.rates)
    assert not np.array_equal(one.rates, gyro.samples.rates)


@settings(max_examples=40, deadline=None)
@given(
    seeds,
    st.sampled_from(["x", "y", "z"]),
    st.floats(0.0, 25.0),
    st.floats(0.05, 10.0),
    st.none() | st.floats(-5.0, 5.0),
)
def test_a_stuck_axis_is_constant_exactly_over_its_window(seed, axis, start, duration, value):
    gyro = _gyro(seed)
    fault = StuckAxisFault(axis=axis, start_s=start, duration_s=duration, value_deg_s=value)
    measured = GyroFault(stuck_axis=fault).measured(gyro)
    column = "xyz".index(axis)
    starts = T[:-1]
    inside = (starts >= start) & (starts < start + duration)
    clean = gyro.samples.rates
    changed = np.zeros_like(clean, dtype=bool)
    changed[:, column] = inside
    assert np.array_equal(measured.rates[~changed], clean[~changed])
    if inside.any():
        stuck = measured.rates[inside, column]
        held = clean[np.flatnonzero(inside)[0], column] if value is None else np.radians(value)
        assert np.all(stuck == held)
    assert np.array_equal(measured.t, gyro.samples.t)


@settings(max_examples=40, deadline=None)
@given(seeds, st.floats(-2.0, 2.0).filter(lambda x: abs(x) > 1e-3))
def test_a_time_offset_shifts_the_time_stamps(seed, offset):
    """Every sample keeps its rates and is stamped ``offset`` later; missing samples pad
    the end the shifted record no longer reaches, so it still spans the pass."""
    gyro = _gyro(seed)
    measured = GyroFault(time_offset=TimeOffsetFault(offset_s=offset)).measured(gyro)
    clean = gyro.samples
    missing = ~np.isfinite(measured.rates).all(axis=1)
    pad = int(missing.sum())
    kept = slice(pad, None) if offset > 0 else slice(0, measured.t.size - pad)
    np.testing.assert_allclose(measured.t[kept], clean.t + offset, rtol=0, atol=1e-12)
    assert np.array_equal(measured.rates[~missing], clean.rates)
    assert pad == int(np.ceil(abs(offset) / clean.dt - 1e-6))
    assert measured.t[0] <= T[0] + 1e-9 and measured.t[-1] >= T[-1] - 1e-9
    record = GyroRecord(measured.t, measured.rates, MEMS_GYRO)
    gyro_timeline(record.samples, np.arange(0.0, 20.0 + 1e-9, 1.0))  # reaches every epoch


def test_the_faults_apply_in_order_scale_stuck_offset():
    gyro = _gyro(2)
    scale = ScaleFactorFault(error=[0.02, -0.01, 0.005])
    stuck = StuckAxisFault(axis="y", start_s=5.0, duration_s=3.0)
    offset = TimeOffsetFault(offset_s=0.5)
    both = GyroFault(scale_factor=scale, stuck_axis=stuck, time_offset=offset).measured(gyro)
    scaled = GyroFault(scale_factor=scale).measured(gyro)
    inside = (T[:-1] >= 5.0) & (T[:-1] < 8.0)
    rates = both.rates[5:]  # after the 5 missing samples of the 0.5 s offset
    assert np.all(rates[inside, 1] == scaled.rates[np.flatnonzero(inside)[0], 1])
    assert np.array_equal(rates[~inside], scaled.rates[~inside])


# --- the simulation ---------------------------------------------------------------------------

CASES = {
    "scale_factor": {"scale_factor": {"error": 0.01}},
    "stuck_axis": {"stuck_axis": {"axis": "y", "start_s": 100.0}},
    "time_offset": {"time_offset": {"offset_s": 0.5}},
}
WINDOW = {"start_utc": "2026-05-10T23:26:20", "duration_s": 400.0}
"""400 s of the default orbit from 200 s into the default pass (sunlit, before the
eclipse) with the first 400 s of the attitude profile: the body turns at 0.01-0.03 deg/s,
the MEMS gyro's bias is about 0.1 deg/s per axis."""
FAST = {**WINDOW, "attitude": {"pitch_peak_s": -1500.0}}
"""The same with the pitch profile of the default pass's 2500-2900 s: the body turns at
0.14-0.16 deg/s about y."""


def _parameters(overrides: dict, window: dict = WINDOW):
    return resolve_parameters(EXPERIMENT, overrides={**window, **overrides})


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_fault_changes_the_measured_samples_only(case):
    """The truth, the bias, the fault-free samples and the prior are those of the run
    without the fault, bit for bit; only the record handed to the estimators differs."""
    clean = filter_inputs(_parameters({}), SEED)[1]
    faulty = filter_inputs(_parameters({"gyro_fault": CASES[case]}), SEED)[1]
    for name in ("true_rates", "bias"):
        assert np.array_equal(getattr(faulty.gyro, name), getattr(clean.gyro, name))
    assert np.array_equal(faulty.gyro.samples.rates, clean.gyro.samples.rates)
    assert np.array_equal(faulty.prior.covariance, clean.prior.covariance)
    assert np.array_equal(faulty.prior.attitude.as_quat(), clean.prior.attitude.as_quat())
    assert not np.array_equal(faulty.record.rates, clean.record.rates, equal_nan=True)


def test_without_a_fault_the_record_is_the_draw_bit_for_bit():
    parameters = _parameters({})
    truth, inputs = filter_inputs(parameters, SEED)
    drawn = simulate_gyro(truth.t, truth.attitude, MEMS_GYRO, child_rng(SEED, GYRO_STREAM))
    assert np.array_equal(inputs.record.t, drawn.samples.t)
    assert np.array_equal(inputs.record.rates, drawn.samples.rates)
    again = simulate_filter_inputs(
        filter_truth(parameters, MEMS_GYRO.rate_hz), MEMS_GYRO, child_rng(SEED, GYRO_STREAM)
    )
    assert inputs.measured is inputs.gyro.samples
    assert np.array_equal(again.record.rates, inputs.record.rates)


# --- the config -------------------------------------------------------------------------------


def test_show_lists_the_fault_tables_and_the_starter_config_loads_them(tmp_path):
    shown = runner.invoke(app, ["show", "wahba-mag-sun"])
    assert shown.exit_code == 0
    for leaf in (
        "gyro_fault(table).scale_factor(table).error",
        "gyro_fault(table).stuck_axis(table).axis",
        "gyro_fault(table).stuck_axis(table).start_s",
        "gyro_fault(table).stuck_axis(table).duration_s",
        "gyro_fault(table).stuck_axis(table).value_deg_s",
        "gyro_fault(table).time_offset(table).offset_s",
    ):
        assert leaf in shown.output, leaf
    fault = {"stuck_axis": {"axis": "y", "start_s": 30.0, "value_deg_s": 0.0}}
    config = tmp_path / "stuck.toml"
    config.write_text(starter_toml(resolve_parameters(EXPERIMENT, overrides={"gyro_fault": fault})))
    loaded = resolve_parameters(EXPERIMENT, config=config)
    assert loaded.gyro_fault == GyroFault(
        stuck_axis=StuckAxisFault(axis="y", start_s=30.0, value_deg_s=0.0)
    )
    assert "[gyro_fault.stuck_axis]" in config.read_text()


@pytest.mark.parametrize(
    "fault",
    [
        {"scale_factor": {"error": [0.01, 0.02]}},
        {"scale_factor": {"error": -1.0}},
        {"stuck_axis": {"axis": "w", "start_s": 0.0}},
        {"stuck_axis": {"axis": "x", "start_s": 0.0, "duration_s": 0.0}},
        {"time_offset": {"offset_s": "0.5"}},
        {"time_offset": {"offset_s": 0.5, "bogus": 1}},
    ],
)
def test_bad_fault_values_are_refused(fault):
    with pytest.raises(ValidationError):
        GyroFault.model_validate(fault)


# --- integrity under each fault ---------------------------------------------------------------

FILTERS = ["mekf", "rts"]


@functools.cache
def _rows(document: str) -> pd.DataFrame:
    overrides = json.loads(document)
    parameters = _parameters({"methods": [], "filters": FILTERS, **overrides})
    return trial(parameters.model_dump(mode="json"), SEED)


def _case_rows(fault: dict, window: dict = WINDOW) -> pd.DataFrame:
    return _rows(json.dumps({**window, "gyro_fault": fault}, sort_keys=True))


def _share_beyond(rows: pd.DataFrame) -> float:
    valid = rows[rows["valid"]]
    return float((valid["nees"] > nees_threshold()).mean())


def _method(rows: pd.DataFrame, method: str) -> pd.DataFrame:
    return rows[rows["method"] == method].reset_index(drop=True)


def test_a_one_percent_scale_factor_is_absorbed_as_a_bias():
    """At the pass's slowly varying rate, ``s omega`` looks like a bias: the filters carry
    it in their bias estimate (its error follows ``s omega``, about 5.7 deg/h about y
    here, to within 4 of its sigmas) and stay consistent, so nothing needs flagging."""
    fault = CASES["scale_factor"]
    rows = _case_rows(fault, FAST)
    truth, inputs = filter_inputs(_parameters({"gyro_fault": fault}, FAST), SEED)
    rate = inputs.gyro.true_rates[truth.epoch_samples[:-1]]
    for method in FILTERS:
        epochs = _method(rows, method)
        assert epochs["valid"].all(), method
        assert _share_beyond(epochs) <= 1e-3, method
        settled = epochs.index[epochs["t_s"] >= 200.0][:-1]
        expected = np.degrees(0.01 * rate[settled]) * 3600.0  # deg/h
        error = epochs.loc[settled, [f"bias_err_{a}_deg_h" for a in "xyz"]].to_numpy()
        sigma = epochs.loc[settled, [f"bias_sigma_{a}_deg_h" for a in "xyz"]].to_numpy()
        assert np.all(np.abs(error - expected) < 4.0 * sigma), method
        assert np.all(np.abs(expected[:, 1]) > 2.0 * sigma[:, 1]), "the fault is seen"


def test_a_time_tag_offset_of_half_a_second_is_absorbed():
    """0.5 s late gyro stamps: the rate error ``omega(t - 0.5) - omega(t)`` at this pass's
    angular accelerations (below 1e-4 deg/s^2) is far below the gyro's noise; the first
    0.5 s are a gap at the start. Every epoch stays valid and consistent."""
    rows = _case_rows(CASES["time_offset"])
    for method in FILTERS:
        epochs = _method(rows, method)
        assert epochs["valid"].all(), method
        assert _share_beyond(epochs) <= 1e-3, method
        assert epochs["nees"].mean() < 4.0, method


STUCK = CASES["stuck_axis"]["stuck_axis"]
DEAD = {"stuck_axis": {**STUCK, "value_deg_s": 0.0}}
"""The y axis reading 0 for 60 s (100-160 s): a rate error of the body's 0.01-0.03 deg/s
plus the bias, 0.1 deg/s."""
STUCK_CASES = {"held": CASES["stuck_axis"], "dead": DEAD}
"""The y axis frozen at its reading, and reading 0, for 60 s (100-160 s)."""
UNCHECKED = {"estimator_options": {"mekf": {"filter": {"max_repeated_readings": 0}}}}
"""The MEKF without the stuck-reading check."""


@pytest.mark.parametrize("method", FILTERS)
@pytest.mark.parametrize("case", sorted(STUCK_CASES))
def test_a_stuck_axis_is_dropped_as_a_gap_and_the_estimates_stay_consistent(case, method):
    """The stuck samples (one axis repeating its reading exactly) are treated as missing:
    the filter holds the last reading before them with the variance growth of a gap, so
    its covariance covers the error of the held rate; the 60 s gap is not longer than
    ``max_gyro_gap_s``, so no epoch is flagged, and no valid epoch lies beyond the
    quantile, for the forward filter and for the RTS pass over it."""
    epochs = _method(_case_rows(STUCK_CASES[case]), method)
    assert epochs["valid"].all()
    assert _share_beyond(epochs) <= 1e-3
    in_fault = epochs["t_s"].between(STUCK["start_s"] + 1.0, STUCK["start_s"] + 60.0)
    sigma = epochs[[f"sigma_{a}_deg" for a in "xyz"]].max(axis=1)
    just_before = epochs["t_s"].between(STUCK["start_s"] - 10.0, STUCK["start_s"] - 1.0)
    assert sigma[in_fault].max() > 2.0 * sigma[just_before].max()  # the gap's growth


def test_without_the_check_a_dead_axis_leaves_valid_epochs_beyond_the_quantile():
    """What the check prevents (measured without it: the MEKF's sigma about y, 0.08 deg,
    is far below what one epoch's vectors resolve, magnetometer 0.46 deg and Sun sensor
    0.11 deg, so its innovations fail their test only once the error is many of its own
    sigmas; 29 valid epochs lie beyond the quantile, a share of 0.075)."""
    rows = _rows(json.dumps({**WINDOW, "gyro_fault": DEAD, **UNCHECKED}, sort_keys=True))
    assert _share_beyond(_method(rows, "mekf")) > 1e-2
