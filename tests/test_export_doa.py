"""``doa-ground``'s export in the recorded-pass format: the pass with rigid-body dynamics and a
gyro, its two priors, and ``attopt estimate`` giving each pass estimator the pass it needs."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from attopt import PassFormatError, load_pass, save_pass
from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.doa_ground.experiment import (
    EXPERIMENT,
    gyro_inputs,
    simulate_pass,
    trial,
)
from attopt.experiments.doa_ground.methods import ekf_method, rts_method
from attopt.experiments.recorded import PassMetadata, RecordedPass
from attopt.experiments.recorded.estimate import estimate, method_rows
from attopt.experiments.recorded.export import exporter
from attopt.experiments.recorded.metadata import PriorEntry
from attopt.experiments.sweep.seeding import trial_seed
from attopt.solvers.doa.ekf import PROCESS_NOISE
from attopt.solvers.pipeline import run_estimators
from attopt.solvers.registry import estimator, estimators
from attopt.solvers.start_hypotheses import flagged_by_start_check, unchecked

runner = CliRunner()
DYNAMICS = "ekf_yang2014"
GYRO_AIDED = "mekf"
TRACK_FIELDS = ("quaternion", "covariance", "valid")
STATUS_COLUMNS = {"valid", "reason", "error"}


@functools.cache
def _setting() -> tuple[dict, np.random.SeedSequence]:
    """A short pass (120 epochs at 1 s, station S1 in view) at 0 dB, L = 100, with the MEKF
    as the one gyro-aided filter: trial 0 runs it."""
    parameters = {
        **EXPERIMENT.parameters,
        **EXPERIMENT.quick_parameters,
        "duration_s": 120.0,
        "step_s": 1.0,
        "row_step_s": 10.0,
        "filters": [GYRO_AIDED],
    }
    setting = next(s for s in EXPERIMENT.grid(parameters) if s["snr_db"] == 0.0)
    return setting, trial_seed(0, 0, 0)


@functools.cache
def _exported() -> RecordedPass:
    return exporter("doa-ground")(*_setting())


def _same_track(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True) for f in TRACK_FIELDS)


def test_exported_doa_pass_estimates_bit_identically_after_save_and_load(tmp_path):
    setting, seed = _setting()
    recorded = _exported()
    loaded = load_pass(save_pass(recorded, tmp_path / "doa"))
    simulated = simulate_pass(setting, seed)
    geometry = simulated.geometry
    truth, inputs = gyro_inputs(simulated.parameters, seed, geometry)
    gyro = inputs.gyro_pass(truth, simulated.pass_.snapshots)
    dynamics = run_estimators(simulated.pass_, [DYNAMICS])[DYNAMICS].track
    gyro_aided = run_estimators(gyro.pass_, [GYRO_AIDED])[GYRO_AIDED].track
    # 120 s from the paper's 98 deg start: the start check confirms no epoch yet
    assert unchecked(dynamics).valid.all() and not dynamics.valid.any()
    # one station in view from the prior's 60 deg sigmas: no single frame can confirm the
    # MEKF's start, so its epochs are flagged; the comparison sees its innovations too
    assert not gyro_aided.valid.any() and np.isfinite(gyro_aided.diagnostics["nis"]).sum() > 100
    for candidate in (recorded, loaded):
        # The position table's orbit frames are the scenario's A_oi, bit for bit.
        assert np.array_equal(candidate.frames.as_quat(), geometry.eci_to_orbit.as_quat())
        assert candidate.pass_.gyro is None and candidate.gyro_pass.dynamics is None
        ours = run_estimators(candidate.pass_, [DYNAMICS])[DYNAMICS].track
        assert _same_track(ours, dynamics) and _same_track(unchecked(ours), unchecked(dynamics))
        ours = run_estimators(candidate.gyro_pass, [GYRO_AIDED])[GYRO_AIDED].track
        assert _same_track(ours, gyro_aided)
        nis = ours.diagnostics["nis"], gyro_aided.diagnostics["nis"]
        assert np.array_equal(*nis, equal_nan=True)
    assert np.array_equal(loaded.truth.as_quat(), geometry.truth.as_quat())


def test_estimating_the_exported_pass_gives_the_trials_rows():
    setting, seed = _setting()
    rows = trial(setting, seed)
    recorded = _exported()
    same = {
        DYNAMICS: ekf_method(PROCESS_NOISE),
        "rts_yang2014": rts_method(PROCESS_NOISE),
        GYRO_AIDED: GYRO_AIDED,
    }
    runs = estimate(recorded, list(same))
    for name, label in same.items():
        theirs = rows[rows["method"] == label].reset_index(drop=True)
        at = recorded.t.searchsorted(theirs["t_s"].to_numpy())
        ours = method_rows(name, runs[name], recorded).iloc[at].reset_index(drop=True)
        assert np.array_equal(ours["t_s"], theirs["t_s"]) and len(ours) == 12
        columns = sorted((set(ours.columns) & set(theirs.columns)) - {"method", "runtime_s"})
        assert {"err_x_deg", "nees", "sigma_z_deg", "q_est_w", "q_true_x", "valid"} <= set(columns)
        # where the start check flags them, the trial's rows show the unchecked run's errors
        run = replace(runs[name], track=unchecked(runs[name].track))
        shown = method_rows(name, run, recorded).iloc[at].reset_index(drop=True)
        checked = flagged_by_start_check(theirs["reason"])
        assert checked.any() == (name != GYRO_AIDED)
        for column in columns:
            if column in STATUS_COLUMNS:
                assert _same_column(ours[column], theirs[column]), (name, column)
            else:
                expected = shown[column].where(checked, ours[column])
                assert _same_column(expected, theirs[column]), (name, column)


def _same_column(a: pd.Series, b: pd.Series) -> bool:
    if not (pd.api.types.is_numeric_dtype(a) and pd.api.types.is_numeric_dtype(b)):
        return a.tolist() == b.tolist()
    return np.array_equal(a.to_numpy(), b.to_numpy(), equal_nan=True)


def test_the_pass_estimators_say_what_carries_their_attitude():
    by_motion = {
        motion: {n for n in estimators("pass") if estimator(n).motion == motion}
        for motion in ("gyro", "dynamics")
    }
    assert by_motion["dynamics"] == {"ekf_yang2014", "rts_yang2014", "bls_yang2014"}
    assert by_motion["gyro"] | by_motion["dynamics"] == set(estimators("pass"))


def test_two_priors_round_trip_through_pass_toml(tmp_path):
    recorded = _exported()
    orbit, eci = recorded.metadata.prior
    assert (orbit.frame, eci.frame) == ("orbit", "eci")
    directory = save_pass(recorded, tmp_path / "doa", fmt="csv")
    text = (directory / "pass.toml").read_text()
    assert text.count("[[prior]]") == 2 and "\n[prior]" not in text
    loaded = load_pass(directory)
    assert loaded.metadata == recorded.metadata
    for candidate in (recorded, loaded):
        start, gyro_start = candidate.pass_.prior, candidate.gyro_pass.prior
        assert start.attitude.as_quat().tolist() == list(orbit.quaternion)
        assert start.rate.tolist() == list(orbit.rate_rad_s) and start.bias is None
        assert gyro_start.attitude.as_quat().tolist() == list(eci.quaternion)
        assert gyro_start.bias.tolist() == list(eci.bias_rad_s) and gyro_start.rate is None


def _prior_text(
    frame: str, covariance: str = "[[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-4]]"
):
    return f'frame = "{frame}"\nquaternion = [0.0, 0.0, 0.0, 1.0]\ncovariance = {covariance}\n'


def test_two_priors_relative_to_one_frame_are_a_format_error():
    text = 'attitude_frame = "orbit"\n[[prior]]\n' + _prior_text("eci") + "[[prior]]\n"
    with pytest.raises(PassFormatError, match=r"pass.toml: key prior: .*at most one prior per "):
        PassMetadata.from_text(text + _prior_text("eci"))
    both = PassMetadata.from_text(text + _prior_text("orbit"))
    assert [p.frame for p in both.prior] == ["eci", "orbit"]
    assert PassMetadata.from_text(both.to_text()) == both


def test_one_prior_table_loads_and_writes_as_before():
    metadata = PassMetadata.from_text('attitude_frame = "eci"\n[prior]\n' + _prior_text("eci"))
    (entry,) = metadata.prior
    assert isinstance(entry, PriorEntry) and metadata.prior_in("eci") is entry
    assert "[prior]\n" in metadata.to_text() and "[[prior]]" not in metadata.to_text()
    assert (
        PassMetadata(attitude_frame="eci").prior == ()
        and "prior" not in PassMetadata(attitude_frame="eci").to_text()
    )
    bad = 'attitude_frame = "eci"\n[prior]\n' + _prior_text("eci", "[[1.0]]") + "colour = 1\n"
    with pytest.raises(PassFormatError, match=r"key prior.colour: Extra inputs"):
        PassMetadata.from_text(bad)


def test_a_prior_no_pass_uses_is_named():
    recorded = _exported()
    unused = recorded.metadata.model_copy(update={"gyro": None})
    tables = {name: frame for name, frame in recorded.tables.items() if name != "gyro"}
    with pytest.raises(PassFormatError, match=r"key prior.1.frame: .*relative to 'orbit', not"):
        RecordedPass(unused, tables)


def test_cli_export_quick_writes_a_loadable_pass(tmp_path):
    out = tmp_path / "pass"
    result = runner.invoke(app, ["export", "doa-ground", str(out), "--quick"])
    assert result.exit_code == 0, result.output
    loaded = load_pass(out)
    assert loaded.metadata.attitude_frame == "orbit" and len(loaded.t) == 6000
    assert loaded.pass_.dynamics is not None and loaded.gyro_pass.gyro is not None
    document = resolve_parameters(EXPERIMENT, quick=True).model_dump(mode="json")
    expected = exporter("doa-ground")(EXPERIMENT.grid(document)[0], trial_seed(0, 0, 0))
    assert loaded.metadata == expected.metadata
    for name, table in expected.tables.items():
        pd.testing.assert_frame_equal(loaded.tables[name], table, check_exact=True)
