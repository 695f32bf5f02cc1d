"""Recorded passes: the on-disk format, its checks, exports and ``attopt estimate``."""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from attopt import MEMS_GYRO, PassFormatError, load_pass, save_pass
from attopt.experiments.cli import app
from attopt.experiments.recorded import PassMetadata, RecordedPass
from attopt.experiments.recorded.estimate import estimate, method_rows
from attopt.experiments.recorded.export import exporter
from attopt.experiments.recorded.metadata import (
    AntennaEntry,
    DoaEntry,
    DynamicsEntry,
    SnrEntry,
    gyro_entry,
    pattern_entry,
)
from attopt.experiments.recorded.records import (
    gyro_table,
    position_table,
    prior_entry,
    truth_table,
    vector_table,
)
from attopt.experiments.sweep.seeding import trial_seed
from attopt.experiments.wahba_mag_sun import experiment as wahba
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.gain_patterns import (
    LIU2023_HELIX,
    AntennaPatterns,
    ParabolicPattern,
    TabulatedPattern,
)
from attopt.formulations.passes import GyroRecord, Prior
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.pipeline import run_estimators

runner = CliRunner()
EPOCHS = np.array([0.0, 1.0, 2.0, 3.0])
TRUTH = Rotation.from_rotvec(
    [[0.1, -0.2, 0.05], [0.12, -0.18, 0.06], [0.13, -0.17, 0.04], [0.1, -0.1, 0.0]]
)
ANTENNAS = (
    AntennaEntry(
        name="helix 1", boresight_body=(0.0, 0.77, 0.64), pattern=pattern_entry(LIU2023_HELIX)
    ),
    AntennaEntry(
        name="helix 2", boresight_body=(0.0, -0.77, 0.64), pattern=pattern_entry(LIU2023_HELIX)
    ),
    AntennaEntry(
        name="dish",
        boresight_body=(0.0, 0.0, 1.0),
        pattern=pattern_entry(ParabolicPattern(30.0, np.radians(20.0), min_gain_dbi=0.0)),
    ),
    AntennaEntry(
        name="measured",
        boresight_body=(0.0, 0.0, -1.0),
        pattern=pattern_entry(TabulatedPattern((0.0, 0.2, 0.4, 0.6), (9.0, 8.5, 7.0, 4.0))),
    ),
)


def _orbit(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    angle = 1.1e-3 * t
    position = 6978.0 * np.column_stack([np.cos(angle), np.sin(angle) * 0.3, np.sin(angle)])
    velocity = 7.5 * np.column_stack([-np.sin(angle), np.cos(angle) * 0.3, np.cos(angle)])
    return position, velocity


def every_table_pass() -> RecordedPass:
    """A small pass with every table and every ``pass.toml`` entry (orbit-frame attitude)."""
    rng = np.random.default_rng(4)
    reference = np.array([[0.6, 0.8, 0.0], [0.0, 0.6, 0.8]])
    body = np.stack([TRUTH[k].apply(reference) for k in range(3)]) + 1e-3 * rng.standard_normal(
        (3, 2, 3)
    )
    gyro_t = np.arange(31) / MEMS_GYRO.rate_hz
    record = GyroRecord(gyro_t, 1e-3 * rng.standard_normal((30, 3)), MEMS_GYRO)
    los = np.array([[0.0, 0.7, 0.7], [0.1, -0.7, 0.7], [0.05, 0.02, 1.0], [0.0, 0.6, 0.8]])
    snr = pd.DataFrame(
        {
            "t_s": [1.0, 2.0, 2.0, 3.0],
            "antenna": [0, 1, 2, 0],
            "transmitter": [7, 8, 9, 7],
            **{f"transmitter_{a}_km": rng.standard_normal(4) for a in "xyz"},
            **{f"los_{a}": los[:, i] for i, a in enumerate("xyz")},
            "p0_dbw": [-132.1, -131.5, -130.2, -133.0],
            "snr_db": [15.2, 14.1, 20.3, 13.9],
            "sigma_db": [1.0, 1.0, 0.5, 1.0],
        }
    )
    doa = pd.DataFrame(
        {
            "t_s": [0.0, 0.0, 3.0],
            "station": [1, 2, 1],
            "theta_rad": [0.3, 0.02, 0.4],
            "phi_rad": [0.5, 2.0, -1.0],
            "cov_theta_theta_rad2": [1e-6, 2e-6, 1e-6],
            "cov_theta_phi_rad2": [1e-8, 0.0, 0.0],
            "cov_phi_theta_rad2": [1e-8, 0.0, 0.0],
            "cov_phi_phi_rad2": [4e-6, 3e-4, 2e-6],
            **{
                f"los_{a}_km": v
                for a, v in zip(
                    "xyz",
                    ([300.0, 10.0, 250.0], [100.0, 5.0, -90.0], [800.0, 900.0, 820.0]),
                    strict=True,
                )
            },
            **{f"station_{a}_km": [np.nan] * 3 for a in "xyz"},
        }
    )
    prior = Prior(TRUTH[0], np.diag([1e-4] * 3 + [1e-6] * 3), bias=np.zeros(3))
    metadata = PassMetadata(
        description="every table",
        start_utc="2026-05-10T23:23:00",
        attitude_frame="orbit",
        gyro=gyro_entry(MEMS_GYRO),
        snr=SnrEntry(noise_dbw=-137.46, threshold_db=6.0, antennas=ANTENNAS),
        doa=DoaEntry(lever_arm_km=(1e-3, 0.0, -2e-3)),
        prior=prior_entry(prior, "eci"),
        dynamics=DynamicsEntry(inertia_kg_m2=((6.6, 0.0, 0.0), (0.0, 8.9, 0.0), (0.0, 0.0, 9.5))),
    )
    tables = {
        "epochs": pd.DataFrame({"t_s": EPOCHS}),
        "gyro": gyro_table(record),
        "vectors": vector_table(EPOCHS[:3], ["sun", "magnetometer"], body, reference, [1e-3, 8e-3]),
        "snr": snr,
        "doa": doa,
        "position": position_table(EPOCHS, *_orbit(EPOCHS)),
        "truth": truth_table(EPOCHS, TRUTH),
    }
    return RecordedPass(metadata, tables)


def _predictions(recorded: RecordedPass) -> list[np.ndarray]:
    attitude = Rotation.from_rotvec([0.11, -0.19, 0.05])
    return [m.predict(attitude)[0] for m in recorded.pass_.measurements() if m is not None]


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_every_table_round_trips_exactly(tmp_path, fmt):
    recorded = every_table_pass()
    loaded = load_pass(save_pass(recorded, tmp_path / "pass", fmt=fmt))
    assert loaded.metadata == recorded.metadata
    assert sorted(loaded.tables) == sorted(recorded.tables)
    for name, frame in recorded.tables.items():
        pd.testing.assert_frame_equal(loaded.tables[name], frame, check_exact=True)
    for ours, theirs in zip(_predictions(loaded), _predictions(recorded), strict=True):
        assert np.array_equal(ours, theirs, equal_nan=True)
    assert np.array_equal(loaded.truth.as_quat(), TRUTH.as_quat())
    assert np.array_equal(loaded.frames.as_quat(), recorded.frames.as_quat())
    assert np.array_equal(loaded.gyro_pass.gyro.rates, recorded.gyro_pass.gyro.rates)
    assert loaded.gyro_pass.prior.attitude.as_quat().tolist() == TRUTH[0].as_quat().tolist()


def test_every_table_builds_the_measurements_it_describes():
    recorded = every_table_pass()
    types = [sorted(type(m).__name__ for m in s.measurements) for s in recorded.pass_.snapshots]
    assert types == [
        ["DoaMeasurement", "VectorMeasurement"],
        ["SnrMeasurement", "VectorMeasurement"],
        ["SnrMeasurement", "VectorMeasurement"],  # a helix's and the dish's SNRs
        ["DoaMeasurement", "SnrMeasurement"],
    ]
    (snr,) = recorded.pass_.snapshots[2].of_type(SnrMeasurement)
    assert snr.epoch.pattern == AntennaPatterns(tuple(a.pattern.pattern() for a in ANTENNAS))
    assert snr.epoch.n_antennas == 4 and snr.epoch.antenna.tolist() == [1, 2]
    assert snr.epoch.sigma_db.tolist() == [1.0, 0.5]
    (doa,) = recorded.pass_.snapshots[0].of_type(DoaMeasurement)
    assert doa.near_axis.tolist() == [False, True]
    assert recorded.pass_.gyro is None and recorded.gyro_pass.gyro is not None
    assert recorded.pass_.dynamics.orbit_frames is recorded.frames
    # The gyro-aided pass models A_bi = A_bo A_oi: its prediction at A_bo A_oi is pass_'s at A_bo.
    inertial = recorded.gyro_pass.measurements()[0].predict(TRUTH[0] * recorded.frames[0])[0]
    assert np.allclose(inertial, recorded.pass_.measurements()[0].predict(TRUTH[0])[0], atol=1e-12)


finite = st.floats(-1e300, 1e300, allow_nan=False, allow_subnormal=True)


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    values=st.lists(st.tuples(*[finite] * 6, st.floats(1e-300, 1e3)), min_size=1, max_size=6),
    fmt=st.sampled_from(["parquet", "csv"]),
)
def test_any_float_round_trips_bit_for_bit(tmp_path_factory, values, fmt):
    rows = np.array(values)
    vectors = pd.DataFrame(
        {
            "t_s": np.arange(len(rows)) * 0.1,
            "sensor": "star tracker",
            **{
                name: rows[:, i]
                for i, name in enumerate(
                    ["body_x", "body_y", "body_z", "reference_x", "reference_y", "reference_z"]
                )
            },
            "sigma_rad": rows[:, 6],
        }
    )
    recorded = RecordedPass(PassMetadata(attitude_frame="eci"), {"vectors": vectors})
    loaded = load_pass(save_pass(recorded, tmp_path_factory.mktemp("pass"), fmt=fmt))
    assert np.array_equal(
        loaded.tables["vectors"].to_numpy(), recorded.tables["vectors"].to_numpy()
    )


@functools.cache
def _wahba(duration_s: float = 120.0):
    setting = {
        **wahba.EXPERIMENT.parameters,
        "duration_s": duration_s,
        "methods": ["quest"],
        "filters": ["mekf"],
    }
    return setting, trial_seed(0, 0, 1)


def _in_memory_passes(setting, seed):
    """The two passes trial(setting, seed) estimates, built as the experiment builds them."""
    parameters = wahba.WahbaMagSunParameters.model_validate(setting)
    vectors = wahba.simulate_pass(wahba.geometry_of(parameters), seed, parameters)
    truth, inputs = wahba.filter_inputs(parameters, seed)
    return vectors.pass_, inputs.gyro_pass(truth, vectors.pass_.snapshots)


def _same_track(a, b) -> bool:
    return all(
        np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
        for f in ("quaternion", "covariance", "valid")
    )


def test_exported_wahba_pass_estimates_bit_identically_after_save_and_load(tmp_path):
    setting, seed = _wahba()
    recorded = exporter("wahba-mag-sun")(setting, seed)
    loaded = load_pass(save_pass(recorded, tmp_path / "wahba"))
    snapshot_pass, gyro = _in_memory_passes(setting, seed)
    quest = run_estimators(snapshot_pass, ["quest"])["quest"].track
    mekf = run_estimators(gyro.pass_, ["mekf"])["mekf"].track
    for candidate in (recorded, loaded):
        assert _same_track(run_estimators(candidate.pass_, ["quest"])["quest"].track, quest)
        assert _same_track(run_estimators(candidate.gyro_pass, ["mekf"])["mekf"].track, mekf)
    assert np.array_equal(
        loaded.truth.as_quat(),
        wahba.geometry_of(wahba.WahbaMagSunParameters.model_validate(setting)).truth.as_quat(),
    )


def test_estimating_the_exported_pass_gives_the_experiments_rows():
    setting, seed = _wahba()
    rows = wahba.trial(setting, seed)
    recorded = exporter("wahba-mag-sun")(setting, seed)
    columns = [
        "err_x_deg",
        "err_y_deg",
        "err_z_deg",
        "sigma_x_deg",
        "sigma_y_deg",
        "sigma_z_deg",
        "nees",
        "valid",
        *(f"q_{kind}_{c}" for kind in ("est", "true") for c in "xyzw"),
    ]
    for name, run in estimate(recorded, ["quest", "mekf"]).items():
        ours = method_rows(name, run, recorded)
        theirs = rows[rows["method"] == name].reset_index(drop=True)
        assert np.array_equal(ours["t_s"], theirs["t_s"])
        for column in columns:
            assert np.array_equal(ours[column], theirs[column], equal_nan=True), (name, column)


def test_experiments_without_an_export_say_so():
    with pytest.raises(ValueError, match=r"noop.*cannot export"):
        exporter("noop")


def _vectors_pass(truth: bool = True) -> RecordedPass:
    t = np.arange(5.0)
    reference = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    attitude = Rotation.from_rotvec(np.outer(t, [0.0, 0.0, 0.01]))
    body = np.stack([attitude[k].apply(reference) for k in range(t.size)])
    tables = {"vectors": vector_table(t, ["sun", "magnetometer"], body, reference, [1e-3, 5e-3])}
    if truth:
        tables["truth"] = truth_table(t, attitude)
    return RecordedPass(PassMetadata(attitude_frame="eci"), tables)


def test_estimate_without_truth_writes_estimates_only(tmp_path):
    directory = save_pass(_vectors_pass(truth=False), tmp_path / "pass", fmt="csv")
    out = tmp_path / "out"
    result = runner.invoke(
        app, ["estimate", str(directory), "--methods", "quest,svd", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    rows = pd.read_parquet(out / "rows.parquet")
    assert [c for c in rows.columns if c.startswith(("err_", "q_true", "nees"))] == []
    assert {"t_s", "q_est_w", "sigma_x_deg", "valid", "reason"} <= set(rows.columns)
    assert rows["valid"].all() and rows["method"].tolist() == ["quest"] * 5 + ["svd"] * 5
    report = (out / "report.md").read_text()
    assert "## Integrity" not in report and "no truth table" in report
    assert (out / "estimates_quest.png").exists() and (out / "summary.csv").exists()


def test_estimate_with_truth_writes_errors_nees_and_integrity(tmp_path):
    directory = save_pass(_vectors_pass(), tmp_path / "pass")
    out = tmp_path / "out"
    result = runner.invoke(
        app, ["estimate", str(directory), "--methods", "quest", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    rows = pd.read_parquet(out / "rows.parquet")
    assert rows["err_x_deg"].abs().max() < 1e-9  # noise-free vectors
    assert np.allclose(
        rows[["q_true_x", "q_true_y", "q_true_z", "q_true_w"]], _vectors_pass().truth.as_quat()
    )
    assert "## Integrity" in (out / "report.md").read_text()
    assert "share beyond 21.1" in (out / "report.md").read_text()
    summary = pd.read_csv(out / "summary.csv")
    assert summary.loc[0, "n_valid"] == 5 and summary.loc[0, "total_rms_deg"] < 1e-9


@pytest.fixture()
def saved(tmp_path):
    return save_pass(_vectors_pass(), tmp_path / "pass")


def _vectors(saved):
    return pd.read_parquet(saved / "vectors.parquet")


def _expect(saved, *parts: str) -> None:
    with pytest.raises(PassFormatError) as error:
        load_pass(saved)
    for part in parts:
        assert part in str(error.value), str(error.value)


def test_a_missing_column_is_named(saved):
    _vectors(saved).drop(columns="sigma_rad").to_parquet(saved / "vectors.parquet")
    _expect(saved, "table vectors, column sigma_rad: missing")


def test_a_column_of_the_wrong_type_is_named(saved):
    _vectors(saved).assign(sigma_rad="small").to_parquet(saved / "vectors.parquet")
    _expect(saved, "table vectors, column sigma_rad, row 0: is not a number")
    _vectors_pass().tables["vectors"].assign(body_x=True).to_parquet(saved / "vectors.parquet")
    _expect(saved, "table vectors, column body_x: must be float, not bool")


def test_a_bad_csv_value_names_its_row(saved):
    frame = _vectors(saved).astype({"sigma_rad": object})
    frame.loc[3, "sigma_rad"] = "0.1 rad"
    (saved / "vectors.parquet").unlink()
    frame.to_csv(saved / "vectors.csv", index=False)
    _expect(saved, "table vectors, column sigma_rad, row 3: is not a number")


@given(row=st.integers(0, 9), column=st.sampled_from(["t_s", "body_y", "reference_z", "sigma_rad"]))
@settings(
    max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
def test_nan_in_a_required_column_names_table_column_and_row(saved, row, column):
    frame = _vectors_pass().tables["vectors"]
    frame.loc[row, column] = np.nan
    frame.to_parquet(saved / "vectors.parquet")
    _expect(saved, f"table vectors, column {column}, row {row}: float value is NaN or infinite")


def test_an_unknown_frame_is_named(saved):
    text = (
        (saved / "pass.toml")
        .read_text()
        .replace('attitude_frame = "eci"', 'attitude_frame = "ecliptic"')
    )
    (saved / "pass.toml").write_text(text)
    _expect(saved, "pass.toml: key attitude_frame", "'ecliptic'")


def test_every_bad_key_is_reported_at_once(saved):
    (saved / "pass.toml").write_text(
        'attitude_frame = "eci"\ncolour = "red"\n[gyro]\nname = "g"\nrate_hz = -1.0\n'
    )
    _expect(
        saved,
        "key colour: Extra inputs",
        "key gyro.rate_hz",
        "(got -1.0)",
        "key gyro.initial_bias_sigma_rad_s: Field required",
    )


def test_a_missing_table_is_named(saved):
    with (saved / "pass.toml").open("a") as toml:
        toml.write(
            PassMetadata(attitude_frame="eci", gyro=gyro_entry(MEMS_GYRO))
            .to_text()
            .split("\n\n", 1)[1]
        )
    _expect(saved, "table gyro: missing")
    (saved / "vectors.parquet").unlink()
    (saved / "pass.toml").write_text('attitude_frame = "eci"\n')
    _expect(saved, "the pass has no epoch")


def test_an_orbit_frame_gyro_pass_needs_the_position_table(tmp_path):
    recorded = every_table_pass()
    directory = save_pass(recorded, tmp_path / "pass")
    (directory / "position.parquet").unlink()
    _expect(directory, "table position: missing")


def test_bad_rows_name_their_table_column_and_row(saved):
    recorded = every_table_pass()
    snr = recorded.tables["snr"].assign(antenna=[0, 1, 4, 0])
    with pytest.raises(PassFormatError, match="table snr, column antenna, row 2: not one of the 4"):
        RecordedPass(recorded.metadata, {**recorded.tables, "snr": snr})
    doa = recorded.tables["doa"].assign(theta_rad=[0.3, 0.02, 2.0])
    with pytest.raises(PassFormatError, match="table doa, row 2: measured theta"):
        RecordedPass(recorded.metadata, {**recorded.tables, "doa": doa})
    truth = recorded.tables["truth"].assign(t_s=[0.0, 1.0, 2.0, 2.5])
    with pytest.raises(
        PassFormatError, match="table truth, column t_s, row 3: not one row per epoch"
    ):
        RecordedPass(recorded.metadata, {**recorded.tables, "truth": truth})
    gyro = recorded.tables["gyro"].assign(t_s=recorded.tables["gyro"]["t_s"] * 2.0)
    with pytest.raises(
        PassFormatError, match="table gyro, column t_s: gyro 'mems' is declared at 10 Hz"
    ):
        RecordedPass(recorded.metadata, {**recorded.tables, "gyro": gyro})
    with pytest.raises(PassFormatError, match="table vectors, column colour: unknown"):
        RecordedPass(
            recorded.metadata,
            {**recorded.tables, "vectors": recorded.tables["vectors"].assign(colour=1)},
        )


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--methods", "quest"], "table vectors, column sigma_rad: missing"),
        (["--methods", "davenport"], "unknown estimator 'davenport'"),
        (["--methods", ","], "--methods names no estimator"),
        (["--methods", "mekf"], "mekf needs a gyro record"),
    ],
)
def test_estimate_exits_2_with_one_line_for_bad_input(saved, arguments, message):
    if "sigma_rad" in message:
        _vectors(saved).drop(columns="sigma_rad").to_parquet(saved / "vectors.parquet")
    result = runner.invoke(app, ["estimate", str(saved), *arguments])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines


def test_estimate_of_a_missing_directory_exits_2(tmp_path):
    result = runner.invoke(app, ["estimate", str(tmp_path / "absent"), "--methods", "quest"])
    assert result.exit_code == 2 and "no such pass directory" in result.output


def test_cli_export_writes_the_trials_pass_and_estimate_reads_it(tmp_path):
    config = tmp_path / "short.toml"
    config.write_text('duration_s = 60.0\nmethods = ["quest"]\nfilters = []\n')
    out = tmp_path / "pass"
    result = runner.invoke(app, ["export", "wahba-mag-sun", str(out), "--config", str(config)])
    assert result.exit_code == 0, result.output
    parameters = wahba.WahbaMagSunParameters.model_validate(
        {**wahba.EXPERIMENT.parameters, "duration_s": 60.0, "methods": ["quest"], "filters": []}
    )
    expected = exporter("wahba-mag-sun")(parameters.model_dump(mode="json"), trial_seed(0, 0, 0))
    loaded = load_pass(out)
    for name, table in expected.tables.items():
        pd.testing.assert_frame_equal(loaded.tables[name], table, check_exact=True)
    estimated = runner.invoke(
        app, ["estimate", str(out), "--methods", "quest", "--out", str(tmp_path / "est")]
    )
    assert estimated.exit_code == 0, estimated.output
    rows = pd.read_parquet(tmp_path / "est" / "rows.parquet")
    trial_rows = wahba.trial(parameters.model_dump(mode="json"), trial_seed(0, 0, 0))
    assert np.array_equal(rows["err_x_deg"], trial_rows["err_x_deg"], equal_nan=True)


def test_cli_export_of_an_experiment_without_export_exits_2(tmp_path):
    result = CliRunner().invoke(app, ["export", "noop", str(tmp_path / "p")])
    assert result.exit_code == 2 and "cannot export" in result.stderr
