"""``wahba-mag-sun``'s parameters: another orbit, every parameter reflected in the rows, and
bad values refused with exit code 2."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from astropy import units as u
from astropy.time import Time
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.environment.geomagnetic import geomagnetic_field_eci
from attopt.experiments.environment.orbit import propagate, satellite_from_tle
from attopt.experiments.environment.shadow import in_cylindrical_shadow
from attopt.experiments.environment.sun import sun_direction_eci
from attopt.experiments.sweep import run_sweep
from attopt.experiments.wahba_mag_sun.experiment import EXPERIMENT, geometry_of
from attopt.experiments.wahba_mag_sun.report import eclipse_spans
from attopt.formulations.conventions import euler321_from_attitude, orbit_frame_attitude
from tests.report_tables import row, table

SEED = np.random.SeedSequence(0, spawn_key=(0, 0))
CBERS2 = {
    "type": "tle",
    "line1": "1 28057U 03049A   06177.78615833  .00000060  00000-0  35940-4 0  1836",
    "line2": "2 28057  98.4283 247.6961 0000884  88.1964 271.9322 14.35478080140550",
}
"""CBERS-2 (NORAD 28057), a 775 km Sun-synchronous orbit: one of sgp4's verification TLEs
(``SGP4-VER.TLE``), epoch 2006-06-26 18:52 UTC."""
DAWN_DUSK = {
    "type": "circular",
    "altitude_km": 700.0,
    "ltan_h": 6.0,
    "epoch_utc": "2025-06-21T00:00:00",
}
"""A generated dawn-dusk Sun-synchronous orbit: no eclipse near the June solstice."""
ROOT = Path(__file__).resolve().parents[1]
QUATERNION = ("x", "y", "z", "w")
ERRORS = ["err_x_deg", "err_y_deg", "err_z_deg"]
BOUNDS = ["bound_x_deg", "bound_y_deg", "bound_z_deg"]


def rows_of(overrides: dict, seed: np.random.SeedSequence = SEED) -> pd.DataFrame:
    """One trial's rows of the parameters after ``overrides`` (validated as a config is)."""
    parameters = resolve_parameters(EXPERIMENT, overrides=overrides)
    (setting,) = EXPERIMENT.grid(parameters.model_dump(mode="json"))
    return EXPERIMENT.trial(setting, seed)


def method(rows: pd.DataFrame, name: str) -> pd.DataFrame:
    return rows[rows["method"] == name].reset_index(drop=True)


def truth(rows: pd.DataFrame) -> Rotation:
    return Rotation.from_quat(rows[[f"q_true_{c}" for c in QUATERNION]].to_numpy())


# --- the orbit --------------------------------------------------------------------------


def test_another_tle_gives_its_own_eclipse_and_vector_geometry():
    """CBERS-2 from 20:00 UTC: the rows' intervals are its cylindrical shadow and their
    bound is the Cramer-Rao bound of its Sun and field directions, both computed here from
    the environment models and ``J = sum sigma^-2 (I - b b^T)``."""
    start, step = "2006-06-26T20:00:00", 2.0
    rows = rows_of(
        {
            "orbit": CBERS2,
            "start_utc": start,
            "duration_s": 600.0,
            "step_s": step,
            "methods": ["quest"],
            "filters": ["mekf"],
            "gyro": {"rate_hz": 1.0},
        }
    )
    quest, mekf = method(rows, "quest"), method(rows, "mekf")
    t = np.arange(0.0, 600.0, step)
    np.testing.assert_array_equal(quest["t_s"], t)
    times = Time(start, scale="utc") + t * u.s
    states = propagate(satellite_from_tle(CBERS2["line1"], CBERS2["line2"]), times)
    sun = sun_direction_eci(times, states.position_eci_km)
    field = geomagnetic_field_eci(
        times, states.longitude_deg, states.latitude_deg, states.height_km
    )
    shadow = in_cylindrical_shadow(states.position_eci_km, sun)
    assert 0 < shadow.sum() < t.size and not shadow[0]  # the pass enters the shadow
    expected = np.where(shadow, "eclipse", "before_eclipse")
    np.testing.assert_array_equal(quest["interval"], expected)
    np.testing.assert_array_equal(quest["valid"], ~shadow)
    assert mekf["valid"].all()

    to_orbit = orbit_frame_attitude(states.position_eci_km, states.velocity_eci_kms)
    attitude = truth(quest)
    body = [
        attitude.apply(to_orbit.apply(v / np.linalg.norm(v, axis=-1, keepdims=True)))
        for v in (sun, field)
    ]
    information = sum(
        (np.eye(3) - np.einsum("ni,nj->nij", b, b)) / sigma**2
        for b, sigma in zip(body, (0.002, 0.008), strict=True)
    )
    bound = np.degrees(np.sqrt(np.diagonal(np.linalg.inv(information), axis1=1, axis2=2)))
    np.testing.assert_allclose(quest.loc[~shadow, BOUNDS], bound[~shadow], rtol=1e-9)
    assert quest.loc[shadow, BOUNDS].isna().all().all()


def test_a_circular_orbit_without_eclipse_is_no_eclipse_throughout():
    rows = rows_of(
        {
            "orbit": DAWN_DUSK,
            "start_utc": "2025-06-21T01:00:00",
            "step_s": 20.0,
            "methods": ["triad", "quest"],
            "filters": [],
        }
    )
    assert set(rows["interval"]) == {"no_eclipse"}
    assert rows["valid"].all() and rows[BOUNDS].notna().all().all()
    assert len(rows) == 2 * 300  # 6000 s at 20 s, a whole orbit (about 99 min) in sunlight


SHORT_CIRCULAR = {
    "start_utc": "2025-06-21T01:00:00",
    "duration_s": 200.0,
    "step_s": 20.0,
    "methods": ["quest"],
    "filters": [],
}


@pytest.fixture(scope="module")
def dawn_dusk_rows() -> pd.DataFrame:
    return rows_of({**SHORT_CIRCULAR, "orbit": DAWN_DUSK})


@pytest.mark.parametrize(
    "change",
    [
        {"altitude_km": 900.0},
        {"inclination_deg": 60.0},
        {"ltan_h": 9.0},
        {"epoch_utc": "2025-06-20T23:00:00"},
        {"eccentricity": 0.01},
        {"argument_of_perigee_deg": 90.0},
        {"mean_anomaly_deg": 30.0},
    ],
    ids=lambda change: ",".join(change),
)
def test_every_element_of_a_circular_orbit_moves_the_satellite(dawn_dusk_rows, change):
    """The bound follows the Sun and field directions along the orbit (none in eclipse), so
    it changes with each element."""
    moved = rows_of({**SHORT_CIRCULAR, "orbit": {**DAWN_DUSK, **change}})
    bounds = dawn_dusk_rows[BOUNDS]
    assert not np.allclose(moved[BOUNDS], bounds, rtol=1e-4, atol=0.0, equal_nan=True)


def test_the_catalogue_number_only_names_the_satellite(dawn_dusk_rows):
    renamed = rows_of({**SHORT_CIRCULAR, "orbit": {**DAWN_DUSK, "satellite_number": 12345}})
    pd.testing.assert_frame_equal(renamed, dawn_dusk_rows)


def test_a_longer_window_holds_two_eclipses_and_the_sunlight_between():
    overrides = {"duration_s": 9000.0, "step_s": 30.0, "methods": ["quest"], "filters": []}
    rows = method(rows_of(overrides), "quest")
    geometry = geometry_of(resolve_parameters(EXPERIMENT, overrides=overrides))
    assert eclipse_spans(rows, 30.0) == list(geometry.eclipses)
    runs = rows["interval"].loc[rows["interval"].shift() != rows["interval"]].tolist()
    assert runs == ["before_eclipse", "eclipse", "between_eclipses", "eclipse", "after_eclipse"]
    np.testing.assert_array_equal(rows["valid"], rows["interval"] != "eclipse")
    (first, _), (second, _) = eclipse_spans(rows, 30.0)
    period = 86400.0 / 14.95201872  # TIMED's mean motion
    assert second - first == pytest.approx(period, abs=30.0)


def test_report_of_a_window_without_eclipse_says_so(tmp_path):
    overrides = {
        "orbit": DAWN_DUSK,
        "start_utc": "2025-06-21T01:00:00",
        "duration_s": 400.0,
        "step_s": 2.0,
        "methods": ["quest"],
        "filters": ["mekf"],
        "gyro": {"name": "tactical", "rate_hz": 5.0, "arw_deg_sqrt_h": 0.05},
    }
    result = run_sweep(
        EXPERIMENT, trials=1, out=tmp_path, workers=1, progress=False, overrides=overrides
    )
    report = (result.out_dir / "report.md").read_text()
    assert "no eclipse in the window (every epoch no_eclipse)" in report
    assert "circular 700 km, Sun-synchronous, ascending node at 6 h" in report
    assert "400 s from 2025-06-21T01:00:00 UTC" in report
    table1 = table(report, "Cilden Guler et al. 2017 Table 1 beside ours")
    assert table1["interval"].tolist() == ["no_eclipse"]
    assert row(table1, {"method": "quest"})["valid"] == "1.000"
    assert "no_eclipse includes the convergence" in report
    assert (
        "`tactical` (5 Hz, angle random walk 0.05 deg/h^(1/2), rate random walk 10 deg/h per "
        "h^(1/2), turn-on bias 360 deg/h) gyro" in report
    )
    filters = table(report, "Gyro-aided filters through the eclipse")
    assert filters["interval"].tolist() == ["no_eclipse"]
    for name in ("error_quest.png", "filter_errors.png", "gyro_bias.png"):
        assert (result.out_dir / name).stat().st_size > 10_000


# --- the window and the attitude --------------------------------------------------------


def test_start_duration_and_step_set_the_epochs():
    """600 s later the eclipse that began 1001 s after the default start begins within
    (400, 401] s; at 5 s steps its first epoch is 405 s."""
    rows = method(
        rows_of(
            {
                "start_utc": "2026-05-10T23:33:00",
                "duration_s": 1500.0,
                "step_s": 5.0,
                "methods": ["q_method"],
                "filters": [],
            }
        ),
        "q_method",
    )
    np.testing.assert_array_equal(rows["t_s"], np.arange(0.0, 1500.0, 5.0))
    eclipse = rows.loc[rows["interval"] == "eclipse", "t_s"]
    assert eclipse.iloc[0] == 405.0 and eclipse.iloc[-1] == 1495.0


def test_attitude_profile_is_the_configured_one():
    profile = {
        "pitch_amplitude_deg": 45.0,
        "pitch_peak_s": 100.0,
        "pitch_period_s": 800.0,
        "roll_amplitude_deg": 10.0,
        "roll_period_s": 400.0,
        "yaw_amplitude_deg": 20.0,
        "yaw_period_s": 1200.0,
    }
    rows = method(
        rows_of({"attitude": profile, "duration_s": 1200.0, "step_s": 50.0, "filters": []}),
        "quest",
    )
    t = rows["t_s"].to_numpy()
    yaw, pitch, roll = np.degrees(euler321_from_attitude(truth(rows))).T
    np.testing.assert_allclose(pitch, 45.0 * np.cos(2 * np.pi * (t - 100.0) / 800.0), atol=1e-9)
    np.testing.assert_allclose(roll, 10.0 * np.sin(2 * np.pi * t / 400.0), atol=1e-9)
    np.testing.assert_allclose(yaw, 20.0 * np.sin(2 * np.pi * t / 1200.0), atol=1e-9)
    at = {time: k for k, time in enumerate(t)}
    assert pitch[at[100.0]] == pytest.approx(45.0) and roll[at[100.0]] == pytest.approx(10.0)
    assert yaw[at[300.0]] == pytest.approx(20.0)
    # the estimates follow this truth: QUEST's errors are at its bound in sunlight
    sunlit = rows[rows["valid"]]
    ratio = np.sqrt(
        (sunlit[ERRORS] ** 2).to_numpy().mean() / (sunlit[BOUNDS] ** 2).to_numpy().mean()
    )
    assert 0.8 < ratio < 1.2


# --- the sensors ------------------------------------------------------------------------


def test_sensor_sigmas_set_the_noise_the_weights_and_the_bound():
    short = {"duration_s": 300.0, "methods": ["q_method"], "filters": []}
    paper = method(rows_of(short), "q_method")
    doubled = method(
        rows_of(
            {**short, "magnetometer": {"sigma_rad": 0.016}, "sun_sensor": {"sigma_rad": 0.004}}
        ),
        "q_method",
    )
    np.testing.assert_allclose(doubled[BOUNDS], 2.0 * paper[BOUNDS], rtol=1e-12)
    # the same draws, twice the noise: twice the errors to first order in sigma
    np.testing.assert_allclose(doubled[ERRORS], 2.0 * paper[ERRORS], rtol=0.05, atol=0.01)
    ratio = np.sqrt(
        (doubled[ERRORS] ** 2).to_numpy().mean() / (paper[ERRORS] ** 2).to_numpy().mean()
    )
    assert ratio == pytest.approx(2.0, rel=0.01)
    np.testing.assert_allclose(doubled["nees"], paper["nees"], rtol=0.05)

    sun_only = method(rows_of({**short, "sun_sensor": {"sigma_rad": 0.02}}), "q_method")
    assert (sun_only[BOUNDS].to_numpy() > 1.01 * paper[BOUNDS].to_numpy()).all()
    assert 2.5 < sun_only["nees"].mean() < 3.5  # weights 1/sigma^2 follow the noise


# --- the filters: gyro, prior, estimators -----------------------------------------------

MEMS_NUMBERS = {
    "name": "mems",
    "rate_hz": 10.0,
    "arw_deg_sqrt_h": 0.3,
    "rrw_deg_h_sqrt_h": 10.0,
    "turn_on_bias_deg_h": 360.0,
}
FILTER_PASS = {"duration_s": 100.0, "methods": ["triad"], "filters": ["mekf"]}


@pytest.fixture(scope="module")
def mems_rows() -> pd.DataFrame:
    return rows_of({**FILTER_PASS, "gyro": "mems"})


def test_gyro_given_by_the_mems_numbers_is_the_mems_preset(mems_rows):
    numbers = rows_of({**FILTER_PASS, "gyro": MEMS_NUMBERS})
    columns = [c for c in mems_rows.columns if c != "runtime_s"]
    pd.testing.assert_frame_equal(numbers[columns], mems_rows[columns])
    assert set(mems_rows["method"]) == {"triad", "mekf"}


@pytest.mark.parametrize(
    ("number", "value"),
    [("rate_hz", 20.0), ("arw_deg_sqrt_h", 3.0), ("rrw_deg_h_sqrt_h", 100.0)],
)
def test_every_gyro_number_changes_the_filter(mems_rows, number, value):
    rows = rows_of({**FILTER_PASS, "gyro": {**MEMS_NUMBERS, number: value}})
    mekf, mems = method(rows, "mekf"), method(mems_rows, "mekf")
    assert not np.allclose(mekf[ERRORS], mems[ERRORS], rtol=1e-6, atol=0.0)
    assert not np.allclose(mekf["sigma_z_deg"], mems["sigma_z_deg"], rtol=1e-6, atol=0.0)
    # the single-frame rows do not depend on the gyro
    pd.testing.assert_frame_equal(method(rows, "triad"), method(mems_rows, "triad"))


def test_turn_on_bias_is_the_prior_bias_sigma():
    gyro = {**MEMS_NUMBERS, "name": "custom", "turn_on_bias_deg_h": 36.0}
    first = method(rows_of({**FILTER_PASS, "gyro": gyro}), "mekf").iloc[0]
    for axis in "xyz":
        assert first[f"bias_sigma_{axis}_deg_h"] == pytest.approx(36.0, rel=1e-12)


def test_initial_sigma_is_the_prior_attitude_sigma(mems_rows):
    tight = method(rows_of({**FILTER_PASS, "initial_sigma_deg": 0.001}), "mekf").iloc[0]
    loose = method(mems_rows, "mekf").iloc[0]
    for axis in "xyz":
        assert tight[f"sigma_{axis}_deg"] <= 0.001
        assert loose[f"sigma_{axis}_deg"] > 0.01  # 10 deg prior: the vectors' accuracy


def test_methods_and_filters_choose_the_rows():
    rows = rows_of({"duration_s": 20.0, "methods": ["foam", "map_nlp"], "filters": ["usque"]})
    assert rows["method"].unique().tolist() == ["foam", "map_nlp", "usque"]
    assert rows.groupby("method").size().eq(20).all()


# --- the documents' examples ------------------------------------------------------------


def toml_blocks(text: str) -> list[str]:
    return re.findall(r"^```toml\n(.*?)^```$", text, flags=re.MULTILINE | re.DOTALL)


def wahba_examples() -> list[str]:
    results = (ROOT / "docs" / "results.md").read_text()
    (section,) = [s for s in results.split("\n## ") if s.startswith("`wahba-mag-sun`")]
    gyro = [b for b in toml_blocks((ROOT / "docs" / "filters.md").read_text()) if "[gyro]" in b]
    return toml_blocks(section) + gyro


def test_the_documents_examples_are_valid_configs(tmp_path):
    examples = wahba_examples()
    assert len(examples) == 2
    for index, text in enumerate(examples):
        config = tmp_path / f"example{index}.toml"
        config.write_text(text)
        resolve_parameters(EXPERIMENT, config=config)
    cbers2 = resolve_parameters(EXPERIMENT, config=tmp_path / "example0.toml")
    assert cbers2.orbit.model_dump() == CBERS2
    gyro = resolve_parameters(EXPERIMENT, config=tmp_path / "example1.toml").gyro
    assert (gyro.name, gyro.rate_hz, gyro.turn_on_bias_deg_h) == ("tactical", 100.0, 10.0)


# --- bad values -------------------------------------------------------------------------

DECAYED = (
    '[orbit]\ntype = "tle"\n'
    'line1 = "1 29141U 85108AA  06170.26783845  .99999999  00000-0  13519-0 0   718"\n'
    'line2 = "2 29141  82.4288 273.4882 0015848 277.2124  83.9133 15.93343074  6828"\n'
)
"""SGP4 verification case 29141: decays within hours of its epoch (2006-06-19)."""


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('[orbit]\ntype = "tle"\nline1 = "1 bogus"\nline2 = "2 bogus"\n', "sgp4 cannot"),
        ('[orbit]\ntype = "kepler"\n', "does not match any of the expected tags"),
        ("[orbit]\ntype = 'circular'\naltitude_km = 50.0\n", "orbit.altitude_km = 50.0"),
        ('start_utc = "2006-06-19T18:00:00"\n' + DECAYED, "SGP4 error 6"),
        ('start_utc = "yesterday"\n', "not an ISO 8601 UTC time"),
        ("duration_s = inf\n", "duration_s = inf"),
        ("step_s = 4000.0\n", "must be shorter than duration_s"),
        ("step_s = 0.25\n", "no samples at the epochs"),
        ("[attitude]\npitch_period_s = 0\n", "attitude.pitch_period_s = 0"),
        ("[attitude]\nroll_amplitude_deg = 200.0\n", "attitude.roll_amplitude_deg = 200.0"),
        ("[magnetometer]\nsigma_rad = 0.0\n", "magnetometer.sigma_rad = 0.0"),
        ("[sun_sensor]\nsigma = 0.002\n", "unknown key 'sun_sensor.sigma'"),
        ("mag_sigma = 0.008\n", "unknown key 'mag_sigma'"),
        ("[gyro]\narw_deg_sqrt_h = -1.0\n", "gyro.arw_deg_sqrt_h = -1.0"),
        ('gyro = "navgrade"\n', "gyro"),
        ("initial_sigma_deg = 0.0\n", "initial_sigma_deg = 0.0"),
        ('methods = ["quest", "davenport"]\n', "unknown methods"),
        ('filters = ["mekf", "quest"]\n', "unknown filters"),
        ('methods = ["quest"]\nfilters = ["mekf", "mekf"]\n', "must be unique"),
    ],
)
def test_bad_values_exit_2_with_one_line_each(tmp_path, text, message):
    config = tmp_path / "bad.toml"
    config.write_text(text)
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["run", "wahba-mag-sun", "--quick", "--config", str(config), "--out", str(out)]
    )
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert lines and all(line.startswith(f"error: {config}: ") for line in lines), lines
    assert any(message in line for line in lines), lines
    assert not out.exists()


def test_every_bad_value_is_reported_at_once(tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text(
        "step_s = 0.0\n[magnetometer]\nsigma_rad = -1.0\n[attitude]\nyaw_period_s = 0\n"
    )
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["run", "wahba-mag-sun", "--config", str(config), "--out", str(out)]
    )
    assert result.exit_code == 2 and not out.exists()
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 3, lines
    for key in ("step_s = 0.0", "magnetometer.sigma_rad = -1.0", "attitude.yaw_period_s = 0"):
        assert any(key in line for line in lines), (key, lines)
