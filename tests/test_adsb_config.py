"""adsb-snr configured: any number of antennas with their own gain patterns, another orbit,
every parameter reflected in the rows, and bad values refused with exit status 2.

Passes are short (12 s at 2 s, 600 modelled flights, 20 minutes into the paper's pass, off
the east coast of North America) so that each configuration runs in about a second: about
90 received messages per epoch on antenna 2, which looks west over the continent, and 5-6
on antenna 1, which looks east over the Atlantic.
"""

from __future__ import annotations

import functools
import json
import math
import re
from pathlib import Path

import airportsdata
import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from attopt.experiments.adsb_snr.experiment import (
    EXPERIMENT,
    NO_GYRO,
    AdsbSnrParameters,
    epoch_statistics,
    noise_free_pass,
    power_offsets,
    simulate_pass,
    trial_pass,
)
from attopt.experiments.adsb_snr.parameters import DEFAULT_BORESIGHTS_BODY, DEFAULT_TLE
from attopt.experiments.adsb_snr.report import observations_section
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry, visible_counts
from attopt.experiments.cli import app
from attopt.experiments.config import flat_items, resolve_parameters
from attopt.experiments.config.loading import deep_merge
from attopt.experiments.environment.orbit import circular_orbit_tle
from attopt.experiments.environment.traffic import MEAN_RADIUS_KM, TrafficModel, sample_traffic
from attopt.experiments.experiment import ReportContext
from attopt.experiments.sweep import run_sweep
from attopt.formulations.gain_patterns import LIU2023_HELIX, TabulatedPattern, gain_dbi_at_angle
from attopt.formulations.snr_model import snr_db
from tests.report_tables import row, table

TINY = {
    "start_utc": "2025-06-02T02:01:00",
    "duration_s": 12.0,
    "step_s": 2.0,
    "traffic": {"n_aircraft": 600},
}
SEED = np.random.SeedSequence(0, spawn_key=(0, 0))
"""The seed of trial 0 of setting 0 (the sweep runner's)."""
TILT = math.radians(50.77)
BORESIGHT_Y = list(DEFAULT_BORESIGHTS_BODY[0])
BORESIGHT_MINUS_Y = list(DEFAULT_BORESIGHTS_BODY[1])
BORESIGHT_X = [math.sin(TILT), 0.0, math.cos(TILT)]
PARABOLIC = {
    "type": "parabolic",
    "peak_gain_dbi": 12.0,
    "beamwidth_deg": 60.0,
    "min_gain_dbi": 4.0,
    "roll_off_db": 12.0,
}
TABLE_DEG = [0.0, 8.0, 16.0, 24.0, 32.0, 40.0]
TABLE_DBI = [float(g) for g in gain_dbi_at_angle(LIU2023_HELIX, np.radians(TABLE_DEG))]
FEW_ESTIMATORS = {"methods": ["nlp"], "filters": [], "gyros": ["mems"]}
runner = CliRunner()


def _parameters(overrides: dict) -> AdsbSnrParameters:
    return resolve_parameters(EXPERIMENT, overrides=deep_merge(TINY, overrides))


@functools.cache
def _epoch_rows(document: str) -> pd.DataFrame:
    """The per-epoch columns every row of trial 0 carries (:func:`epoch_statistics`), for a
    JSON document of overrides."""
    parameters = _parameters(json.loads(document))
    scenario, noisy = trial_pass(parameters, SEED)
    receiver = parameters.receiver
    columns = epoch_statistics(scenario, noisy, receiver.snr_sigma_db, receiver.threshold_db)
    return pd.DataFrame(columns)


def epoch_rows(overrides: dict | None = None) -> pd.DataFrame:
    return _epoch_rows(json.dumps(overrides or {}, sort_keys=True))


@functools.cache
def _trial_rows(document: str) -> pd.DataFrame:
    parameters = _parameters(json.loads(document))
    return EXPERIMENT.trial(EXPERIMENT.grid(parameters.model_dump(mode="json"))[0], SEED)


def trial_rows(overrides: dict | None = None) -> pd.DataFrame:
    """Trial 0 with ``overrides`` (by default the NLP and no filter)."""
    return _trial_rows(json.dumps(deep_merge(FEW_ESTIMATORS, overrides or {}), sort_keys=True))


def _antenna_columns(rows: pd.DataFrame) -> list[str]:
    return [c for c in rows.columns if re.fullmatch(r"n_obs_antenna\d+", c)]


def _table_csv(tmp_path: Path, shift_db: float = 0.0) -> Path:
    path = tmp_path / "pattern.csv"
    gains = np.asarray(TABLE_DBI) + shift_db
    pd.DataFrame({"angle_deg": TABLE_DEG, "gain_dbi": gains}).to_csv(path, index=False)
    return path


# --- one antenna and three antennas -----------------------------------------------------------


def _observations_table(rows: pd.DataFrame, parameters: AdsbSnrParameters) -> dict[str, str]:
    """The report's observation table of ``rows`` (one trial)."""
    context = ReportContext(parameters.model_dump(mode="json"), rows, pd.DataFrame(), Path("."))
    return row(table(observations_section(context), "(Liu et al. 2023 Fig. 8)"), {})


def test_one_antenna_counts_its_messages_and_cannot_see_the_rotation_about_its_boresight():
    """The bound is in body axes: the rotation about the tilted boresight (0, -sin b, cos b)
    moves y and z, so those two bounds are NaN and x is finite; the direction columns give
    the boresight itself (up to sign).  The gyro carries the unseen rotation: the filter
    stays valid."""
    overrides = {
        "antennas": [{"boresight_body": BORESIGHT_MINUS_Y}],
        "methods": ["nlp", "deterministic"],
        "filters": ["mekf_snr"],
    }
    rows = trial_rows(overrides)
    assert _antenna_columns(rows) == ["n_obs_antenna1"]
    np.testing.assert_array_equal(rows["n_obs"], rows["n_obs_antenna1"])
    assert (rows["n_obs"] > 10).all()
    assert (rows["n_unobservable"] == 1).all()
    direction = rows[["unobservable_x", "unobservable_y", "unobservable_z"]].to_numpy()
    np.testing.assert_allclose(np.abs(direction @ BORESIGHT_MINUS_Y), 1.0, atol=1e-9)
    for bound in ("bound", "bound_truncated"):
        assert (np.isfinite(rows[f"{bound}_x_deg"]) & (rows[f"{bound}_x_deg"] > 0)).all()
        assert rows[[f"{bound}_y_deg", f"{bound}_z_deg"]].isna().all().all()
    single = rows[rows["gyro"] == NO_GYRO]
    assert not single["valid"].any()
    assert single["reason"].str.contains("unobservable").all()
    assert single[["sigma_x_deg", "sigma_y_deg", "sigma_z_deg", "q_est_w"]].isna().all().all()
    filtered = rows[rows["method"] == "mekf_snr"]
    assert filtered["valid"].all()
    assert np.isfinite(filtered[["sigma_x_deg", "sigma_y_deg", "sigma_z_deg"]]).all().all()
    observed = _observations_table(rows, _parameters(overrides))
    assert observed["epochs with an unobservable rotation"] == "1.0000"


def test_a_nadir_antenna_leaves_only_yaw_unbounded():
    # its 41.7 deg lobe covers a ground circle of about 560 km radius: the whole fleet
    nadir = {"antennas": [{"boresight_body": [0.0, 0.0, 2.0]}], "traffic": {"n_aircraft": 10_000}}
    rows = epoch_rows(nadir)
    assert (rows["n_obs"] >= 3).all()
    assert rows[["bound_x_deg", "bound_y_deg"]].notna().all().all()
    assert rows["bound_z_deg"].isna().all()
    direction = rows[["unobservable_x", "unobservable_y", "unobservable_z"]]
    np.testing.assert_allclose(direction, [[0.0, 0.0, 1.0]] * 6, atol=1e-9)


def test_three_antennas_with_three_patterns(tmp_path):
    """Counts of every antenna, the bias over every received message, antenna 3's SNRs from
    its table, solutions near the bound, and the report and figures of three antennas."""
    overrides = deep_merge(
        TINY,
        {
            "antennas": [
                {"boresight_body": BORESIGHT_Y},
                {"boresight_body": BORESIGHT_MINUS_Y, "gain": PARABOLIC},
                {
                    "boresight_body": BORESIGHT_X,
                    "gain": {"type": "table", "file": str(_table_csv(tmp_path))},
                },
            ],
            "methods": ["nlp"],
            "filters": ["rts_snr"],
            "gyros": ["mems"],
        },
    )
    out = tmp_path / "out"
    sweep = run_sweep(EXPERIMENT, trials=1, out=out, workers=1, progress=False, overrides=overrides)
    rows = sweep.rows
    columns = _antenna_columns(rows)
    assert columns == ["n_obs_antenna1", "n_obs_antenna2", "n_obs_antenna3"]
    np.testing.assert_array_equal(rows["n_obs"], rows[columns].sum(axis=1))
    assert (rows["n_obs_antenna3"] >= 2).all()
    assert (rows["n_unobservable"] == 0).all()
    # the bias is the mean over every received message, of all three antennas
    parameters = AdsbSnrParameters.model_validate(sweep.parameters)
    scenario = noise_free_pass(parameters)
    noisy = simulate_pass(scenario, np.random.default_rng(SEED), 1.0, 6.0)
    kept = noisy.received
    error = pd.Series(noisy.measured_db[kept] - noisy.true_snr_db[kept])
    expected = error.groupby(scenario.epoch_index[kept]).mean()
    nlp = rows[rows["method"] == "nlp"]
    np.testing.assert_allclose(nlp["snr_bias_db"], expected.to_numpy(), rtol=1e-12)
    # antenna 3's true SNRs are its table's, evaluated here on its own
    third = scenario.antenna == 2
    table_pattern = TabulatedPattern(tuple(np.radians(TABLE_DEG)), tuple(TABLE_DBI))
    body = scenario.truth[scenario.epoch_index[third]].apply(scenario.los_orbit[third])
    link = parameters.link_budget
    alone = snr_db(
        np.eye(3), body, BORESIGHT_X, scenario.p0_dbw[third], link.noise_power_dbw, table_pattern
    )
    np.testing.assert_allclose(scenario.true_snr_db[third], alone, atol=1e-9)
    # solved near the bound by every method
    assert rows["valid"].all()
    errors = nlp[["err_x_deg", "err_y_deg", "err_z_deg"]].to_numpy()
    bounds = nlp[["bound_x_deg", "bound_y_deg", "bound_z_deg"]].to_numpy()
    assert np.abs(errors / bounds).max() < 5.0
    text = (out / "report.md").read_text()
    assert "main lobes of the 3 antenna(s)" in text
    assert row(table(text, "(Liu et al. 2023 Fig. 8)"), {})[
        "epochs with an unobservable rotation"
    ] == ("0.0000")
    assert (out / "observations.png").stat().st_size > 10_000


# --- the orbit ----------------------------------------------------------------------------------


def test_a_circular_orbit_at_another_altitude_changes_the_geometry():
    orbit = {
        "type": "circular",
        "altitude_km": 1100.0,
        "inclination_deg": 60.0,
        "ltan_h": 14.0,
        "epoch_utc": "2025-06-02T00:00:00",
        "eccentricity": 0.001,
        "argument_of_perigee_deg": 90.0,
        "mean_anomaly_deg": 10.0,
        "satellite_number": 12345,
    }
    parameters = _parameters({"orbit": orbit, "start_utc": "2025-06-02T00:10:00"})
    line1, line2 = parameters.orbit.tle()
    assert line1.startswith("1 12345U") and line2[8:16].strip() == "60.0000"
    geometry = build_adsb_geometry(parameters)
    altitude = np.linalg.norm(geometry.position_eci_km, axis=-1) - 6378.137
    np.testing.assert_allclose(altitude, 1100.0, atol=15.0)
    assert geometry.prefilter_rad > build_adsb_geometry(_parameters({})).prefilter_rad
    # no aircraft above the limb is left out by the wider pre-filter
    wide = visible_counts(geometry, 85.0)
    assert wide.sum() > 0
    rows = epoch_rows({"orbit": orbit, "start_utc": "2025-06-02T00:10:00"})
    assert not np.array_equal(rows["n_visible"], epoch_rows()["n_visible"])


# --- every parameter, reflected in the rows -----------------------------------------------------


def _attitude(t: np.ndarray, yaw, pitch, roll) -> np.ndarray:
    """``R1(roll) R2(pitch) R3(yaw)`` (Liu et al. 2023 eq. 8) by hand, rad, ``(N, 3, 3)``."""

    def r1(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])

    def r2(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])

    def r3(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])

    return np.stack([r1(r) @ r2(p) @ r3(y) for y, p, r in zip(yaw, pitch, roll, strict=True)])


ATTITUDE = {
    "yaw_amplitude_deg": 8.0,
    "yaw_period_s": 50.0,
    "yaw_phase_deg": 30.0,
    "pitch_amplitude_deg": -6.0,
    "pitch_period_s": 40.0,
    "pitch_phase_deg": 45.0,
    "roll_amplitude_deg": 2.0,
    "roll_period_s": 30.0,
    "roll_phase_deg": -20.0,
}


def test_the_attitude_profile_is_the_true_attitude_of_the_rows():
    rows = trial_rows({"attitude": ATTITUDE})
    nlp = rows[rows["method"] == "nlp"]
    assert nlp["valid"].all()
    t = nlp["t_s"].to_numpy()
    a = ATTITUDE

    def angle(axis, wave):
        phase = 2 * np.pi * t / a[f"{axis}_period_s"] + np.radians(a[f"{axis}_phase_deg"])
        return np.radians(a[f"{axis}_amplitude_deg"] * wave(phase))

    expected = _attitude(t, angle("yaw", np.cos), angle("pitch", np.sin), angle("roll", np.sin))
    q_true = nlp[["q_true_x", "q_true_y", "q_true_z", "q_true_w"]].to_numpy()
    np.testing.assert_allclose(Rotation.from_quat(q_true).as_matrix(), expected, atol=1e-12)
    valid = nlp[nlp["valid"]]
    estimate = Rotation.from_quat(valid[["q_est_x", "q_est_y", "q_est_z", "q_est_w"]].to_numpy())
    truth = Rotation.from_quat(valid[["q_true_x", "q_true_y", "q_true_z", "q_true_w"]].to_numpy())
    error = np.degrees((estimate * truth.inv()).as_rotvec())
    np.testing.assert_allclose(error, valid[["err_x_deg", "err_y_deg", "err_z_deg"]], atol=1e-9)
    assert nlp[~nlp["valid"]]["q_est_w"].isna().all()


def _shift(overrides: dict) -> np.ndarray:
    """True SNR of the visible rows with ``overrides`` minus that of the defaults."""
    base = noise_free_pass(_parameters({}))
    other = noise_free_pass(_parameters(overrides))
    np.testing.assert_array_equal(base.aircraft, other.aircraft)
    return other.true_snr_db - base.true_snr_db


@pytest.mark.parametrize(
    ("overrides", "expected_db"),
    [
        ({"traffic": {"transmit_power_w": 500.0}}, 10 * math.log10(2.0)),
        ({"traffic": {"transmit_gain_dbi": 1.5}}, 1.5),
        ({"traffic": {"frequency_hz": 2.18e9}}, -20 * math.log10(2.0)),
        ({"receiver": {"polarisation_loss_db": 1.0}}, 2.0),
        ({"receiver": {"noise_temperature_k": 1000.0}}, -10 * math.log10(2.0)),
        ({"receiver": {"bandwidth_hz": 1.3e6}}, 10 * math.log10(2.0)),
    ],
)
def test_link_budget_numbers_shift_every_true_snr_and_the_received_count(overrides, expected_db):
    np.testing.assert_allclose(_shift(overrides), expected_db, atol=1e-9)
    more, fewer = (epoch_rows(overrides)["n_obs"], epoch_rows()["n_obs"])
    assert (more >= fewer).all() if expected_db > 0 else (more <= fewer).all()
    assert not np.array_equal(more, fewer)


def test_threshold_and_snr_noise_set_what_is_received():
    strict = epoch_rows({"receiver": {"threshold_db": 9.0}})
    assert (strict["n_obs"] < epoch_rows()["n_obs"]).all()
    noisy = epoch_rows({"receiver": {"snr_sigma_db": 3.0}})
    # a selection on more noise keeps a larger upward bias (module docstring of experiment.py)
    assert noisy["snr_bias_db"].mean() > 2.0 * epoch_rows()["snr_bias_db"].mean() > 0


def test_power_offsets_change_the_received_messages():
    rows = epoch_rows({"traffic": {"power_offset_sigma_db": 3.0}})
    assert not np.array_equal(rows["n_obs"], epoch_rows()["n_obs"])
    offsets = power_offsets(noise_free_pass(_parameters({})), SEED, 3.0)
    assert 2.5 < np.std(offsets) < 3.5


@pytest.mark.parametrize(
    "overrides",
    [
        {"traffic": {"n_aircraft": 1500}},
        {"traffic": {"seed": 5}},
        {"start_utc": "2025-06-02T01:41:00"},
        {"orbit": {"type": "tle", "line1": "", "line2": ""}},  # lines set below
    ],
    ids=["n_aircraft", "seed", "start_utc", "tle"],
)
def test_traffic_start_and_orbit_change_what_is_visible(overrides):
    if "orbit" in overrides:
        line1, line2 = circular_orbit_tle("2025-06-01T00:00:00", 99999, 800.0, 97.8, 226.31)
        overrides = {"orbit": {"type": "tle", "line1": line1, "line2": line2}}
        assert (line1, line2) != DEFAULT_TLE
    assert not np.array_equal(epoch_rows(overrides)["n_visible"], epoch_rows()["n_visible"])


def test_traffic_bands_and_routes_shape_the_flights():
    overrides = {
        "traffic": {
            "height_min_km": 1.0,
            "height_max_km": 2.0,
            "speed_min_m_s": 100.0,
            "speed_max_m_s": 110.0,
            "route_min_km": 1000.0,
            "route_max_km": 3000.0,
            "route_scale_km": 500.0,
            "international_weight": 1.0,
            "metropolitan_weight": 1.0,
        }
    }
    traffic = build_adsb_geometry(_parameters(overrides)).traffic
    default = build_adsb_geometry(_parameters({})).traffic
    assert traffic.height_km.min() >= 1.0 and traffic.height_km.max() <= 2.0
    assert traffic.speed_mps.min() >= 100.0 and traffic.speed_mps.max() <= 110.0
    route_km = traffic.route_angle_rad * MEAN_RADIUS_KM
    assert route_km.min() >= 1000.0 - 1e-6 and route_km.max() <= 3000.0 + 1e-6
    # the 500 km preference scale favours short routes: against a flat preference in the band
    flat = TrafficModel(min_route_km=1000.0, max_route_km=3000.0, route_scale_km=1e9)
    unpreferred = sample_traffic(3000, np.random.default_rng(0), flat)
    assert np.median(route_km) < np.median(unpreferred.route_angle_rad * MEAN_RADIUS_KM) - 200.0
    # without the size factors, airports of metropolitan areas are rarer origins
    metropolitan = [
        code for area in airportsdata.load_iata_macs().values() for code in area["airports"]
    ]
    share = np.isin(traffic.origin, metropolitan).mean()
    assert share < 0.5 * np.isin(default.origin, metropolitan).mean()
    assert not np.array_equal(epoch_rows(overrides)["n_visible"], epoch_rows()["n_visible"])


@pytest.mark.parametrize(
    "gain",
    [
        {"type": "cos_power", "peak_gain": 20.0, "exponent": 4.0, "min_gain_dbi": 6.0},
        PARABOLIC,
        {"type": "table", "angle_deg": TABLE_DEG[:-1], "gain_dbi": TABLE_DBI[:-1]},
    ],
    ids=["cos_power", "parabolic", "table"],
)
def test_gain_patterns_set_the_main_lobes(gain):
    edge_deg = {
        "cos_power": math.degrees(math.acos((10 ** (6.0 / 10) / 20.0) ** (1 / 4.0))),
        "parabolic": 60.0 * math.sqrt((12.0 - 4.0) / 12.0),  # theta sqrt((Gmax - Gmin) / C)
        "table": TABLE_DEG[-2],
    }[gain["type"]]
    antennas = [{"boresight_body": b, "gain": gain} for b in (BORESIGHT_Y, BORESIGHT_MINUS_Y)]
    parameters = _parameters({"antennas": antennas})
    rows = epoch_rows({"antennas": antennas})
    # a hair inside the edge computed by hand, and a hair outside: the rows' count lies between
    inside = visible_counts(build_adsb_geometry(parameters), edge_deg - 1e-6).sum(axis=1)
    outside = visible_counts(build_adsb_geometry(parameters), edge_deg + 1e-6).sum(axis=1)
    assert (inside <= rows["n_visible"]).all() and (rows["n_visible"] <= outside).all()
    assert not np.array_equal(rows["n_visible"], epoch_rows()["n_visible"])


def test_a_table_read_from_a_file_and_a_stronger_table_receive_more(tmp_path):
    antennas = [
        {"boresight_body": b, "gain": {"type": "table", "file": str(_table_csv(tmp_path))}}
        for b in (BORESIGHT_Y, BORESIGHT_MINUS_Y)
    ]
    read = _parameters({"antennas": antennas}).antennas[0].gain
    assert read.angle_deg == TABLE_DEG and read.gain_dbi == pytest.approx(TABLE_DBI)
    stronger = [
        {"boresight_body": b, "gain": {"type": "table", "angle_deg": TABLE_DEG, "gain_dbi": g}}
        for b in (BORESIGHT_Y, BORESIGHT_MINUS_Y)
        for g in [[x + 3.0 for x in TABLE_DBI]]
    ]
    assert (
        epoch_rows({"antennas": stronger})["n_obs"] > epoch_rows({"antennas": antennas})["n_obs"]
    ).all()


def test_duration_and_step_set_the_epochs():
    rows = epoch_rows({"duration_s": 9.0, "step_s": 3.0})
    np.testing.assert_array_equal(rows["t_s"], [0.0, 3.0, 6.0])


def test_wrong_minima_are_checked_every_kth_epoch():
    rows = trial_rows({"wrong_minimum_every": 2})
    checked = rows.dropna(subset=["wrong_minimum"])
    assert set(checked["t_s"]) == {0.0, 4.0, 8.0}


def test_methods_and_the_two_step_minimum_per_antenna():
    """With 250 flights antenna 1 receives two messages per epoch here; the two-step method
    needs three per antenna unless ``deterministic_min_per_antenna = 2``."""
    sparse = {"methods": ["deterministic"], "traffic": {"n_aircraft": 250}}
    strict = trial_rows(sparse)
    lenient = trial_rows(deep_merge(sparse, {"deterministic_min_per_antenna": 2}))
    assert set(strict["method"]) == {"deterministic"}
    two = (strict[["n_obs_antenna1", "n_obs_antenna2"]].min(axis=1) == 2).to_numpy()
    assert two.any()
    rule = "at least 3 observations each"
    assert not strict["valid"][two].any() and strict["reason"][two].str.contains(rule).all()
    assert not lenient["reason"][two].str.contains(rule).any()
    assert lenient["valid"][two].any()


FOG = {
    "name": "fog",
    "arw_deg_sqrt_h": 0.05,
    "rrw_deg_h_sqrt_h": 1.0,
    "turn_on_bias_deg_h": 10.0,
    "rate_hz": 10.0,
}
SIGMAS = ["sigma_x_deg", "sigma_y_deg", "sigma_z_deg"]
ERRORS = ["err_x_deg", "err_y_deg", "err_z_deg", "q_est_w"]


def _method(rows: pd.DataFrame, method: str, gyro: str = "mems") -> pd.DataFrame:
    return rows[(rows["method"] == method) & (rows["gyro"] == gyro)].reset_index(drop=True)


def test_a_gyro_given_by_its_numbers_is_its_own_row_label():
    rows = trial_rows({"methods": [], "filters": ["mekf_snr"], "gyros": ["mems", FOG]})
    assert set(rows["gyro"]) == {"mems", "fog"}
    fog, mems = _method(rows, "mekf_snr", "fog"), _method(rows, "mekf_snr", "mems")
    # the turn-on bias sigma (10 deg/h against the MEMS unit's 360 deg/h) bounds the filter's
    assert (fog["bias_sigma_x_deg_h"] <= 10.0 + 1e-9).all()
    assert (mems["bias_sigma_x_deg_h"].iloc[:2] > 10.0).all()


FILTER_OPTIONS = [
    # option, value, filter it changes, a row of another method it leaves alone
    ("initial_sigma_deg", 1.0, "mekf_snr", ("nlse", NO_GYRO)),
    ("paper_sigma_deg", 5.0, "mekf_paper", ("mekf_snr", "mems")),
    ("filter_snr_model", "gaussian", "mekf_snr", ("mekf_paper", "mems")),
    ("offset_prior_sigma_db", 0.2, "fg_batch_offsets", ("mekf_snr", "mems")),
]


NO_TEST = {"consistency_window": 0}
"""A filter's or smoother's ``filter`` options without the consistency test."""


def test_filter_options_change_their_filters_rows_alone():
    base = {
        "methods": ["nlse"],
        "filters": ["mekf_paper", "mekf_snr", "fg_batch_offsets"],
        "traffic": {"power_offset_sigma_db": 1.0},
    }
    for option, value, method, (other, gyro) in FILTER_OPTIONS:
        # the SNR filters model no power offsets: with them, their consistency test flags
        # every epoch (test_unmodelled_power_offsets_are_flagged), so their options are
        # seen without offsets; the smoother's residual test flags this 12 s pass too
        # (test_unmodelled_power_offsets_are_flagged), so it is off for its option
        world = (
            deep_merge(base, {"estimator_options": {method: {"filter": NO_TEST}}})
            if method == "fg_batch_offsets"
            else {**base, "traffic": {}}
        )
        old = trial_rows(world)
        new = trial_rows(deep_merge(world, {option: value}))
        changed, before = _method(new, method), _method(old, method)
        if option == "initial_sigma_deg":
            assert (changed[SIGMAS].iloc[0] < before[SIGMAS].iloc[0]).all()
        elif option == "paper_sigma_deg":
            assert (changed[SIGMAS].iloc[-1] > before[SIGMAS].iloc[-1]).all()
        else:
            assert not changed["err_x_deg"].equals(before["err_x_deg"]), option
        pd.testing.assert_frame_equal(
            _method(new, other, gyro)[ERRORS], _method(old, other, gyro)[ERRORS]
        )


AMBIGUOUS = "fewer than two antennas with a determined boresight direction"
"""The two-step method's flag where an antenna's few cones fit a second boresight (at the
start of the pass antenna 1 sees three to a few aircraft; offsets and outliers move its
cones, so the flag can come before the residual test's)."""


def _flags(method: str) -> tuple[str, ...]:
    """The reasons a snapshot method gives an epoch whose SNRs the model does not fit."""
    return ("model mismatch", AMBIGUOUS) if method == "deterministic" else ("model mismatch",)


@pytest.mark.parametrize("offset_db", [1.0, 2.0])
def test_unmodelled_power_offsets_are_flagged(offset_db):
    """Transmitter power offsets the SNR model does not have (real transponders differ by
    several dB): the snapshot least squares' residuals fail their chi-square test
    (``model mismatch``) and the filter's innovations their consistency test
    (``inconsistent``), so their epochs are flagged, not reported valid with a covariance
    their error contradicts, and the smoother's residual test flags every epoch of the
    smoother without offsets.  The smoother that models the offsets is valid where its
    residuals pass their test and consistent where valid (in this 12 s pass it starts
    from a filter without offsets and its residuals at the solution are about 3 times
    their rows: flagged), and without offsets every one of them is valid (but the two-step
    method's epochs with a second boresight)."""
    methods = ["deterministic", "nlse", "nlp"]
    chosen = {"methods": methods, "filters": ["mekf_snr", "fg_batch", "fg_batch_offsets"]}
    rows = trial_rows({**chosen, "traffic": {"power_offset_sigma_db": offset_db}})
    for method in methods:  # (measured: 4 to 6 of the 6 epochs at 1 dB, all at 2 dB)
        flagged = _method(rows, method, NO_GYRO)["reason"].str.startswith(_flags(method))
        assert flagged.mean() >= (0.5 if offset_db < 2.0 else 1.0), method
    # the MEKF's first epoch is its prior updated by that epoch's single frame: valid only
    # where the snapshot least squares fit (measured: the first of the 6 at 1 dB, none at 2)
    mekf = _method(rows, "mekf_snr")
    fits = _method(rows, "nlp", NO_GYRO)["valid"].to_numpy()
    assert not (mekf["valid"].to_numpy() & ~fits).any()
    assert not mekf["valid"].iloc[1:].any()
    assert mekf.loc[~mekf["valid"], "reason"].str.startswith("inconsistent").all()
    plain = _method(rows, "fg_batch")  # the smoother without offsets: its residual test
    assert not plain["valid"].any()  # (at 2 dB its optimiser does not converge either)
    flags = ("inconsistent: the residuals", "smoother did not converge")
    assert plain["reason"].str.startswith(flags).all()
    smoother = _method(rows, "fg_batch_offsets")
    valid = smoother["valid"]
    assert (smoother["reason"][~valid].str.startswith("inconsistent: the residuals")).all()
    assert (smoother["nees"][valid] < 21.1).all()
    clean = trial_rows({**chosen, "filters": ["mekf_snr", "fg_batch_offsets"]})
    assert (clean["valid"] | clean["reason"].str.startswith(AMBIGUOUS)).all()
    assert clean.loc[~clean["valid"], "method"].eq("deterministic").all()


def test_a_burst_of_outlier_snrs_is_flagged_and_its_end_recovered():
    """Every SNR 20 dB off for 10 s (``[receiver.outliers]``, a receiver fault): each
    snapshot method's residual test flags exactly the burst's epochs (``model mismatch``)
    and is valid from the first epoch after it; the SNR filters and the smoother gate the
    outliers, carry the attitude on the gyro through the burst and stay consistent."""
    burst = {"start_s": 10.0, "duration_s": 10.0, "offset_db": 20.0}
    snapshot = ["deterministic", "nlse", "nlp", "nlp_truncated"]
    rows = trial_rows(
        {
            "duration_s": 40.0,
            "methods": snapshot,
            "filters": ["mekf_snr", "rts_snr", "fg_batch"],
            "receiver": {"outliers": burst},
        }
    )
    for method in snapshot:
        epochs = _method(rows, method, NO_GYRO)
        inside = (epochs["t_s"] >= 10.0) & (epochs["t_s"] < 20.0)
        assert epochs.loc[inside, "reason"].str.startswith(_flags(method)).all(), method
        outside = epochs.loc[~inside]
        assert (outside["valid"] | outside["reason"].str.startswith(AMBIGUOUS)).all(), method
    for method in ("mekf_snr", "rts_snr", "fg_batch"):
        epochs = _method(rows, method)
        assert epochs["valid"].all() and (epochs["nees"] < 21.1).all(), method


def test_a_gyro_fault_changes_every_gyros_filter_rows_alone():
    """``[gyro_fault]`` corrupts the samples of each gyro of ``gyros`` that the filters get
    (here one axis stuck at zero for 4 s); the single-frame rows do not see it."""
    chosen = {"methods": ["nlp"], "filters": ["mekf_snr"], "gyros": ["mems", FOG]}
    fault = {"stuck_axis": {"axis": "x", "start_s": 2.0, "duration_s": 4.0, "value_deg_s": 0.0}}
    old, new = trial_rows(chosen), trial_rows({**chosen, "gyro_fault": fault})
    for gyro in ("mems", "fog"):
        changed, before = _method(new, "mekf_snr", gyro), _method(old, "mekf_snr", gyro)
        assert changed.loc[changed["t_s"] <= 2.0, ERRORS].equals(
            before.loc[before["t_s"] <= 2.0, ERRORS]
        )
        assert not changed["err_x_deg"].equals(before["err_x_deg"]), gyro
    pd.testing.assert_frame_equal(
        _method(new, "nlp", NO_GYRO).drop(columns="runtime_s"),
        _method(old, "nlp", NO_GYRO).drop(columns="runtime_s"),
    )


def test_a_spoofed_position_moves_the_estimates_not_the_truth():
    """An aircraft broadcasting a position 1000 km off (``[traffic.spoofer]``): what is
    received, the truth and the bounds are those without it, the estimates move
    (``tests/test_spoofed_position.py`` tests the spoofer and the exclusion)."""
    spoofer = {"traffic": {"spoofer": {"aircraft": [27], "offset_km": 1000.0}}}
    pd.testing.assert_frame_equal(epoch_rows(spoofer), epoch_rows())
    moved = trial_rows(spoofer)["err_x_deg"].to_numpy() != trial_rows()["err_x_deg"].to_numpy()
    assert moved.any()


def test_the_sky_tables_change_what_the_receiver_hears():
    """``[traffic.transmitters]``, ``[receiver.collisions]`` with ``squitter_rate_hz``,
    ``[receiver.chain]`` and ``[receiver.aircraft_model]`` each change the counts, the bias
    or the stated noise of the received messages (``tests/test_adsb_sky.py`` tests each
    part)."""
    paper = epoch_rows()
    transmitters = epoch_rows({"traffic": {"transmitters": {"class1_share": 0.5}}})
    assert transmitters["n_obs"].sum() < paper["n_obs"].sum()
    # 1000 messages/s from each of about 90 aircraft per channel, none captured: every
    # message overlaps another
    jammed = {"capture_margin_db": 60.0}
    crowded = {"traffic": {"squitter_rate_hz": 1000.0}, "receiver": {"collisions": jammed}}
    assert epoch_rows(crowded)["n_obs"].sum() < 0.1 * paper["n_obs"].sum()
    chain = epoch_rows({"receiver": {"chain": {"table_messages": 200, "calibrated": False}}})
    assert (chain["snr_bias_db"] > 0.0).all() and (paper["snr_bias_db"].abs() < 0.4).all()
    # the receiver's aircraft model widens every SNR's sigma: the NLP's grows with it
    modelled = trial_rows({"receiver": {"aircraft_model": {"antennas": False}}})
    assert (modelled["sigma_x_deg"] > trial_rows()["sigma_x_deg"]).all()


def test_every_parameter_is_overridden_by_a_test():
    """The key paths of the defaults, a circular orbit and the other gain patterns and gyro
    tables, each set to another value by one of the tests above."""
    source = Path(__file__).read_text()
    defaults = flat_items(EXPERIMENT.parameters)
    leaves = {re.sub(r"\[\d+\]", "", path).split(".")[-1] for path in defaults}
    leaves |= {"altitude_km", "inclination_deg", "ltan_h", "epoch_utc", "eccentricity"}
    leaves |= {"argument_of_perigee_deg", "mean_anomaly_deg", "satellite_number"}
    leaves |= {"beamwidth_deg", "roll_off_db", "angle_deg", "gain_dbi", "file"}
    leaves |= {"arw_deg_sqrt_h", "rrw_deg_h_sqrt_h", "turn_on_bias_deg_h", "rate_hz", "name"}
    missing = sorted(leaf for leaf in leaves if f'"{leaf}"' not in source)
    assert not missing


# --- bad values ---------------------------------------------------------------------------------

BAD = """
duration_s = 60.0
start_utc = "yesterday"
antennas = []
[orbit]
type = "tle"
line1 = "1 99999U"
line2 = "2 99999"
[attitude]
roll_period_s = 0.0
[traffic]
height_min_km = 13.0
n_aircraft = 0
[receiver]
snr_sigma_db = -1.0
"""


def test_bad_values_exit_2_naming_each(tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text(BAD)
    result = runner.invoke(
        app, ["run", "adsb-snr", "--config", str(config), "--out", str(tmp_path / "out")]
    )
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.startswith("error:")]
    text = "\n".join(lines)
    for expected in (
        "start_utc = 'yesterday'",
        "antennas = []",
        "orbit",
        "attitude.roll_period_s = 0.0",
        "traffic.n_aircraft = 0",
        "receiver.snr_sigma_db = -1.0",
    ):
        assert expected in text, (expected, text)
    assert "Traceback" not in result.output
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[antennas]]\nboresight_body = [0.0, 0.0, 0.0]\n", "antennas[0].boresight_body"),
        ("[[antennas]]\nboresight_body = [0.0, 1.0]\n", "antennas[0].boresight_body"),
        (
            '[[antennas]]\nboresight_body = [0.0, 0.0, 1.0]\n[antennas.gain]\ntype = "dish"\n',
            "antennas[0].gain",
        ),
        (
            '[[antennas]]\nboresight_body = [0.0, 0.0, 1.0]\n[antennas.gain]\ntype = "table"\n'
            'file = "missing.csv"\n',
            "cannot read gain table",
        ),
        ('gyros = [{name = "a", rate_hz = 10.0}, {name = "b", rate_hz = 20.0}]\n', "same rate"),
        ('[orbit]\ntype = "circular"\naltitude_km = 50.0\n', "orbit.altitude_km = 50.0"),
        ("[traffic]\nroute_min_km = 5000.0\nroute_max_km = 4000.0\n", "route_min_km must be below"),
        ("[traffic]\nheight_min_km = 13.0\n", "height_min_km must not exceed height_max_km"),
        ('gyros = ["mems", {name = "mems"}]\n', "gyros need distinct names"),
        ('[orbit]\ntype = "circular"\naltitude_km = 7000.0\n', "no Sun-synchronous orbit"),
        ("n_antennas = 3\n", "unknown key 'n_antennas'"),
    ],
)
def test_each_bad_value_exits_2_with_a_one_line_message(tmp_path, text, message):
    config = tmp_path / "bad.toml"
    config.write_text(text)
    result = runner.invoke(
        app, ["run", "adsb-snr", "--config", str(config), "--out", str(tmp_path / "out")]
    )
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output
