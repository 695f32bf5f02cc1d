"""adsb-snr's passes exported in the recorded-pass format: bit-identical estimates after a
save and a load, the trial's rows from ``attopt estimate``, per-antenna patterns, the
transmitters' ECI positions and the CLI."""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from attopt import load_pass, save_pass
from attopt.experiments.adsb_snr import experiment as adsb
from attopt.experiments.adsb_snr.filters import adsb_gyro_truth, gyro_inputs, snr_measurements
from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.config.loading import deep_merge
from attopt.experiments.recorded.estimate import estimate, method_rows
from attopt.experiments.recorded.export import exporter
from attopt.experiments.sweep.seeding import trial_seed
from attopt.formulations.conventions import orbit_frame_attitude
from attopt.solvers.pipeline import run_estimators
from attopt.solvers.registry import estimator

SHORT = {
    "start_utc": "2025-06-02T02:01:00",
    "duration_s": 20.0,
    "traffic": {"n_aircraft": 2000},
    "methods": ["nlse", "nlp"],
    "filters": ["mekf_snr"],
    "gyros": ["mems"],
}
TILT = math.radians(50.77)
THREE_PATTERNS = {
    "antennas": [
        {"boresight_body": [0.0, math.sin(TILT), math.cos(TILT)]},
        {
            "boresight_body": [0.0, -math.sin(TILT), math.cos(TILT)],
            "gain": {
                "type": "parabolic",
                "peak_gain_dbi": 12.0,
                "beamwidth_deg": 60.0,
                "min_gain_dbi": 4.0,
            },
        },
        {
            "boresight_body": [math.sin(TILT), 0.0, math.cos(TILT)],
            "gain": {"type": "cos_power", "peak_gain": 10.0, "exponent": 4.0},
        },
    ]
}
SEED = trial_seed(0, 0, 0)
runner = CliRunner()


def _setting(overrides: dict | None = None) -> dict:
    parameters = resolve_parameters(adsb.EXPERIMENT, overrides=deep_merge(SHORT, overrides or {}))
    return adsb.EXPERIMENT.grid(parameters.model_dump(mode="json"))[0]


@functools.cache
def _exported(document: str):
    setting = json.loads(document)
    return setting, exporter("adsb-snr")(setting, SEED)


def exported(overrides: dict | None = None):
    return _exported(json.dumps(_setting(overrides), sort_keys=True))


def _in_memory_passes(setting: dict):
    """The trial's own passes: the snapshots of the single-frame methods and the filters'
    gyro-aided pass of the first gyro."""
    parameters = adsb.AdsbSnrParameters.model_validate(setting)
    _, noisy = adsb.trial_pass(parameters, SEED)
    inputs = gyro_inputs(parameters, SEED, 0)
    truth = adsb_gyro_truth(parameters, inputs.model.rate_hz)
    gyro = inputs.gyro_pass(truth, snr_measurements(noisy.epochs, parameters.filter_snr_model))
    return adsb.snr_snapshots(noisy.epochs), gyro.pass_


def _same_track(a, b) -> bool:
    return all(
        np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
        for f in ("quaternion", "covariance", "valid")
    )


RECEIVER_CHAIN = {"receiver": {"chain": {"table_messages": 200}}}
"""The simulated receiver chain: one stated sigma per SNR and no reception threshold."""


@pytest.mark.parametrize(
    "overrides", [None, THREE_PATTERNS, RECEIVER_CHAIN], ids=["paper", "three_patterns", "chain"]
)
def test_exported_pass_estimates_bit_identically_after_save_and_load(tmp_path, overrides):
    setting, recorded = exported(overrides)
    loaded = load_pass(save_pass(recorded, tmp_path / "adsb"))
    snapshots, gyro_pass = _in_memory_passes(setting)
    nlp = estimator("nlp").solve_sequence(snapshots)
    mekf = run_estimators(gyro_pass, ["mekf"])["mekf"].track
    assert nlp.valid.sum() >= 15
    for candidate in (recorded, loaded):
        assert _same_track(run_estimators(candidate.pass_, ["nlp"])["nlp"].track, nlp)
        assert _same_track(run_estimators(candidate.gyro_pass, ["mekf"])["mekf"].track, mekf)
    parameters = adsb.AdsbSnrParameters.model_validate(setting)
    truth = adsb.noise_free_pass(parameters).truth
    assert np.array_equal(loaded.truth.as_quat(), truth.as_quat())
    assert len(loaded.metadata.snr.antennas) == len(parameters.antennas)


def test_estimating_the_exported_pass_gives_the_trials_rows():
    setting, recorded = exported()
    rows = adsb.trial(setting, SEED)
    columns = [
        *(f"err_{a}_deg" for a in "xyz"),
        *(f"sigma_{a}_deg" for a in "xyz"),
        "nees",
        "valid",
        *(f"q_{kind}_{c}" for kind in ("est", "true") for c in "xyzw"),
    ]
    for name, label in (("nlse", "nlse"), ("nlp", "nlp"), ("mekf", "mekf_snr")):
        ours = method_rows(name, estimate(recorded, [name])[name], recorded)
        theirs = rows[rows["method"] == label].reset_index(drop=True)
        assert np.array_equal(ours["t_s"], theirs["t_s"])
        for column in columns:
            assert np.array_equal(ours[column], theirs[column], equal_nan=True), (name, column)


def test_every_epoch_and_every_received_message_is_exported():
    setting, recorded = exported()
    parameters = adsb.AdsbSnrParameters.model_validate(setting)
    scenario, noisy = adsb.trial_pass(parameters, SEED)
    snr = recorded.tables["snr"]
    assert len(recorded.tables["epochs"]) == scenario.n_epochs == len(recorded.t)
    assert len(snr) == int(noisy.received.sum())
    counts = np.bincount(snr["antenna"], minlength=2)
    rows = adsb.trial(setting, SEED).query("method == 'nlp'")
    assert counts.tolist() == [rows["n_obs_antenna1"].sum(), rows["n_obs_antenna2"].sum()]


def test_transmitter_positions_are_eci_along_the_stored_lines_of_sight():
    _, recorded = exported()
    snr, position = recorded.tables["snr"], recorded.tables["position"]
    at = np.searchsorted(position["t_s"], snr["t_s"])
    satellite = position[[f"position_{a}_km" for a in "xyz"]].to_numpy()[at]
    velocity = position[[f"velocity_{a}_km_s" for a in "xyz"]].to_numpy()[at]
    to_orbit = orbit_frame_attitude(satellite, velocity)
    transmitter = snr[[f"transmitter_{a}_km" for a in "xyz"]].to_numpy()
    direction = transmitter - satellite
    range_km = np.linalg.norm(direction, axis=1)
    los = to_orbit.apply(direction / range_km[:, None])
    stored = snr[["los_x", "los_y", "los_z"]].to_numpy()
    # ECEF -> ECI of the aircraft by astropy's matrices against the satellite's own ECI
    # position from SGP4: the same direction to well under a microradian
    assert np.max(np.linalg.norm(los - stored, axis=1)) < 1e-7
    assert np.all((range_km > 500.0) & (range_km < 4000.0))


def test_cli_export_writes_the_pass_and_estimate_reads_it(tmp_path):
    config = tmp_path / "short.toml"
    config.write_text(
        'start_utc = "2025-06-02T02:01:00"\nduration_s = 10.0\nmethods = ["nlp"]\n'
        'filters = []\ngyros = ["mems"]\n[traffic]\nn_aircraft = 2000\n'
    )
    out = tmp_path / "pass"
    result = runner.invoke(app, ["export", "adsb-snr", str(out), "--config", str(config)])
    assert result.exit_code == 0, result.output
    estimated = runner.invoke(
        app, ["estimate", str(out), "--methods", "nlp", "--out", str(tmp_path / "est")]
    )
    assert estimated.exit_code == 0, estimated.output
    rows = pd.read_parquet(tmp_path / "est" / "rows.parquet")
    assert rows["valid"].sum() >= 5 and np.isfinite(rows["nees"][rows["valid"]]).all()
