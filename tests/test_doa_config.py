"""``doa-ground``'s parameters: another set-up runs, every parameter reaches the rows, bad
values exit 2.

Trials run on a 60-s pass at the start of the default orbit (the default station ``S1`` in
view at polar angles of 59-62 deg; the three stations of :data:`THREE` near the
sub-satellite track), one ``Q`` and no gyro-aided rows unless a test needs them.
"""

from __future__ import annotations

import functools
import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import tomli_w
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.config import ConfigError, resolve_parameters
from attopt.experiments.config.components import Station
from attopt.experiments.doa_ground.experiment import (
    EXPERIMENT,
    DoaGroundParameters,
    grid,
    music_estimator,
)
from attopt.experiments.doa_ground.parameters import (
    SATELLITE_TLE,
    SPEED_OF_LIGHT_M_S,
    DoaScenario,
)
from attopt.experiments.doa_ground.scenario import build_geometry, stations_ecef_km
from attopt.experiments.environment.orbit import circular_orbit_tle
from attopt.experiments.sweep import run_sweep
from attopt.formulations.conventions import attitude_from_euler321
from attopt.formulations.rigid_body import YANG2014_INERTIA

SHORT: dict[str, Any] = {
    "duration_s": 60.0,
    "settle_s": 30.0,
    "row_step_s": 5.0,
    "table1_snr_db": [0.0],
    "table2_snapshots": [],
    "process_noise": [1e-12],
    "filter_trials": 0,
}
THREE = [
    {"name": "Alpha", "latitude_deg": 2.0, "longitude_deg": -56.0},
    {"name": "Bravo", "latitude_deg": 8.0, "longitude_deg": -62.0, "height_m": 2000.0},
    {"name": "Charlie", "latitude_deg": -5.0, "longitude_deg": -52.0},
]
"""Three stations within 8 deg of the first minute's sub-satellite points (0-3.4 deg N,
57-58 deg W): all visible, the first near the array axis."""
EKF = "ekf_yang2014_q1e-12"


def parameters(**overrides: Any) -> DoaGroundParameters:
    """The short pass's parameters with ``overrides`` (tables merge key by key)."""
    return resolve_parameters(EXPERIMENT, overrides={**SHORT, **overrides})


def trial(seed: int = 7, **overrides: Any) -> pd.DataFrame:
    """The rows of the first setting's trial ``seed`` (cached: the tests only read them)."""
    return _trial(json.dumps(overrides, sort_keys=True), seed)


@functools.cache
def _trial(overrides: str, seed: int) -> pd.DataFrame:
    (setting, *_) = grid(parameters(**json.loads(overrides)).model_dump(mode="json"))
    return EXPERIMENT.trial(setting, np.random.SeedSequence(seed))


def music(rows: pd.DataFrame) -> pd.Series:
    (row,) = rows[rows["method"] == "music"].itertuples(index=False)
    return pd.Series(row._asdict())


def method(rows: pd.DataFrame, name: str) -> pd.DataFrame:
    return rows[rows["method"] == name].reset_index(drop=True)


def uca_crb_deg2(theta: np.ndarray, snr_db: float, snapshots: int, array: Any) -> tuple:
    """Mean closed-form CRBs of ``theta`` and ``phi`` on a UCA (deg^2): ``(1 + 1/(M SNR)) /
    (L M SNR (k r cos theta)^2)`` and the same with ``sin theta`` (Stoica and Nehorai 1990)."""
    snr = 10.0 ** (snr_db / 10.0)
    kr = 2.0 * np.pi * array.radius_m / array.wavelength_m
    scale = (1.0 + 1.0 / (array.n_elements * snr)) / (snapshots * array.n_elements * snr * kr**2)
    return tuple(
        float(np.mean(scale / f(theta) ** 2)) * np.degrees(1.0) ** 2 for f in (np.cos, np.sin)
    )


def test_the_default_orbit_is_the_documented_sgp4_tle() -> None:
    """Yang et al. 2014 sec. 4.1's orbit as generated (scenario docstring): 800 km, 98.60 deg,
    RAAN 101.81 deg, epoch the default start."""
    defaults = DoaScenario()
    assert defaults.orbit.tle() == SATELLITE_TLE
    assert SATELLITE_TLE == circular_orbit_tle(
        defaults.start_utc, 99003, 800.0, 98.60, 101.81, 1.0e-4, 0.0, 0.0
    )


def test_three_stations_and_an_eight_element_array_run_through_the_sweep(tmp_path: Path) -> None:
    """A TOML set-up of three stations and an 8-element array: the rows count each
    station's DOAs (all visible, their sum the total), their CRBs are the closed-form bound
    of 8 elements, the report lists the three stations and the effective config has them."""
    config = tmp_path / "three.toml"
    config.write_text(tomli_w.dumps({**SHORT, "stations": THREE, "array": {"n_elements": 8}}))
    result = run_sweep(
        EXPERIMENT, trials=1, out=tmp_path / "out", config=config, workers=1, progress=False
    )
    rows = result.rows
    row = music(rows)
    counts = [row[f"doa_count_station{k}"] for k in (1, 2, 3)]
    assert "doa_count_station4" not in rows and min(counts) > 0
    assert sum(counts) == row["doa_count"]
    assert sum(row[f"doa_accepted_station{k}"] for k in (1, 2, 3)) == row["doa_accepted"]
    chosen = parameters(stations=THREE, array={"n_elements": 8})
    geometry = build_geometry(chosen)
    assert counts == geometry.visible.sum(axis=0).tolist()
    assert geometry.visible.sum(axis=1).max() == 3
    for k in (1, 2, 3):
        theta = geometry.doa[geometry.visible[:, k - 1], k - 1, 0]
        theta_crb, phi_crb = uca_crb_deg2(theta, 0.0, 100, chosen.array)
        assert row[f"doa_crb_theta_station{k}_deg2"] == pytest.approx(theta_crb, rel=1e-9)
        assert row[f"doa_crb_phi_station{k}_deg2"] == pytest.approx(phi_crb, rel=1e-9)
    assert "t" not in rows and set(method(rows, EKF)["t_s"]) == set(np.arange(0.0, 60.0, 5.0))
    stations = (result.out_dir / "report.md").read_text().split("## Stations")[1]
    assert all(f"| {s['name']} |" in stations for s in THREE) and "| S1 |" not in stations
    effective = resolve_parameters(EXPERIMENT, config=result.out_dir / "config.toml")
    assert effective == chosen


def test_attitude_columns_are_the_estimate_and_the_truth() -> None:
    """``q_est_*`` and ``q_true_*`` give back the rows' error columns (``C_bo``; for the EKF
    and RTS rows also where only their start check flags them, which show the unchecked
    run's estimates), and the truth at ``t_s = 0`` is ``attitude.initial_euler_deg``."""
    rows = trial(stations=THREE)
    for name in (EKF, "rts_yang2014_q1e-12", "wahba"):
        chosen = method(rows, name)
        chosen = chosen[chosen["err_x_deg"].notna()]
        assert len(chosen) > 0, name
        estimate = Rotation.from_quat(chosen[[f"q_est_{c}" for c in "xyzw"]].to_numpy())
        truth = Rotation.from_quat(chosen[[f"q_true_{c}" for c in "xyzw"]].to_numpy())
        error = np.degrees((estimate * truth.inv()).as_rotvec())
        np.testing.assert_allclose(error, chosen[[f"err_{a}_deg" for a in "xyz"]], atol=1e-9)
    first = method(rows, EKF).iloc[0]
    start = attitude_from_euler321(*np.radians([3.0, -2.0, 2.0]))
    assert Rotation.from_quat([first[f"q_true_{c}"] for c in "xyzw"]).approx_equal(start, 1e-12)
    wahba = method(rows, "wahba")
    assert wahba.loc[~wahba["valid"], [f"q_est_{c}" for c in "xyzw"]].isna().all().all()


def test_a_circular_orbit_with_the_papers_elements_is_nearly_the_default() -> None:
    """``type = "circular"``: 800 km, 98.60 deg, ascending node at 20:00 (RAAN from the Sun:
    101.81 deg rounded) at the start: the DOAs nearly the default's, not the same."""
    orbit = {
        "type": "circular",
        "altitude_km": 800.0,
        "inclination_deg": 98.6,
        "ltan_h": 20.0,
        "epoch_utc": "2025-03-01T00:00:00",
        "satellite_number": 99003,
    }
    default, circular = music(trial()), music(trial(orbit=orbit))
    assert circular["doa_crb_theta_deg2"] != default["doa_crb_theta_deg2"]
    assert circular["doa_crb_theta_deg2"] == pytest.approx(default["doa_crb_theta_deg2"], rel=0.02)


@pytest.mark.parametrize("inclination_deg", [98.6, 51.6])
def test_the_orbit_frames_follow_the_configured_tle(inclination_deg: float) -> None:
    """The orbit normal of the geometry's orbit frames (``-y``) has the TLE's inclination
    (TEME and GCRS equators differ by the precession since 2000, about 0.35 deg)."""
    lines = circular_orbit_tle("2025-03-01T00:00:00", 1, 700.0, inclination_deg, 30.0)
    orbit = {"type": "tle", "line1": lines[0], "line2": lines[1]}
    geometry = build_geometry(DoaScenario.model_validate({"orbit": orbit, "duration_s": 60.0}))
    normal = -geometry.eci_to_orbit.inv().apply([0.0, 1.0, 0.0])
    np.testing.assert_allclose(np.degrees(np.arccos(normal[:, 2])), inclination_deg, atol=0.5)
    count = music(trial(orbit=orbit))["doa_count"]
    assert count == geometry.visible.sum() != music(trial())["doa_count"]


def test_a_later_start_is_the_same_orbit_later() -> None:
    """``start_utc`` 300 s later: the lines of sight at its t = 0 are the default pass's at
    t = 300 s (the same TLE propagated); the rows see other DOAs."""
    default = build_geometry(DoaScenario(duration_s=310.0, step_s=5.0))
    later = build_geometry(
        DoaScenario(start_utc="2025-03-01T00:05:00", duration_s=10.0, step_s=5.0)
    )
    np.testing.assert_allclose(
        np.linalg.norm(later.line_of_sight_km[0], axis=-1),
        np.linalg.norm(default.line_of_sight_km[60], axis=-1),
        atol=1e-4,
    )
    shifted = music(trial(start_utc="2025-03-01T00:05:00"))
    assert shifted["doa_crb_theta_deg2"] != music(trial())["doa_crb_theta_deg2"]


def test_minimum_elevation_and_station_height_reach_the_rows() -> None:
    """A 60-deg minimum elevation counts only the epochs above it; a station 2 km up sits 2 km
    along its ellipsoid normal and is seen at other DOAs."""
    low, high = music(trial(stations=THREE)), music(trial(stations=THREE, min_elevation_deg=60.0))
    geometry = build_geometry(parameters(stations=THREE, min_elevation_deg=60.0))
    above = (geometry.elevation_deg >= 60.0).sum(axis=0)
    assert [high[f"doa_count_station{k}"] for k in (1, 2, 3)] == above.tolist()
    assert high["doa_count"] < low["doa_count"]
    ground = {**THREE[1], "height_m": 0.0}
    up, ground_position = (stations_ecef_km([Station(**s)]) for s in (THREE[1], ground))
    np.testing.assert_allclose(up[0] - ground_position[0], 2.0 * ground_position[1], atol=1e-6)
    flat = music(trial(stations=[THREE[0], ground, THREE[2]]))
    assert flat["doa_crb_theta_station2_deg2"] != low["doa_crb_theta_station2_deg2"]
    assert flat["doa_crb_theta_station1_deg2"] == low["doa_crb_theta_station1_deg2"]


def test_the_rigid_body_truth_follows_the_attitude_table() -> None:
    """Another inertia and wheel: the inertial angular momentum ``A_bi^T (I omega + h)`` is
    conserved with the configured ``I`` and ``h`` (not with the default ones); the start is
    ``initial_euler_deg`` off Earth pointing with the orbit rate plus
    ``initial_rate_offset_deg_s``; the rows' truth and the filters' dynamics follow."""
    attitude = {
        "inertia_kg_m2": [[10.0, 0.5, 0.0], [0.5, 6.0, 0.0], [0.0, 0.0, 12.0]],
        "wheel_momentum_nms": [0.02, -0.3, 0.01],
        "initial_euler_deg": [-4.0, 1.0, 6.0],
        "initial_rate_offset_deg_s": [0.01, -0.02, 0.003],
    }
    chosen = parameters(attitude=attitude, duration_s=300.0, step_s=1.0)
    geometry = build_geometry(chosen)
    inertial = (geometry.truth * geometry.eci_to_orbit).inv()

    def drift(inertia: np.ndarray, wheel: np.ndarray) -> float:
        momentum = inertial.apply(geometry.rate @ inertia.T + wheel)
        return float(np.abs(momentum - momentum[0]).max() / np.linalg.norm(momentum[0]))

    assert drift(chosen.attitude.inertia, chosen.attitude.wheel_momentum) < 1e-9
    assert drift(YANG2014_INERTIA, np.array([0.0, -0.1, 0.0])) > 1e-4
    np.testing.assert_array_equal(geometry.dynamics.inertia, chosen.attitude.inertia)
    np.testing.assert_array_equal(geometry.dynamics.wheel_momentum, chosen.attitude.wheel_momentum)
    start = attitude_from_euler321(*np.radians(attitude["initial_euler_deg"]))
    assert geometry.truth[0].approx_equal(start, 1e-12)
    turn = (geometry.eci_to_orbit[1] * geometry.eci_to_orbit[0].inv()).as_rotvec()
    orbit_rate = geometry.truth[0].apply(-turn / chosen.step_s)
    np.testing.assert_allclose(
        np.degrees(geometry.rate[0] - orbit_rate), attitude["initial_rate_offset_deg_s"], atol=2e-4
    )  # the frame's finite-difference rate: the orbit plane wobbles by about 1e-6 rad/s
    rows, default = method(trial(attitude=attitude), EKF), method(trial(), EKF)
    q_true = [f"q_true_{c}" for c in "xyzw"]
    assert not np.allclose(rows[q_true].to_numpy()[-1], default[q_true].to_numpy()[-1], atol=1e-3)


def test_the_array_and_the_carrier_reach_the_crb_columns() -> None:
    """Radius, element count and wavelength (or frequency) set the rows' DOA CRB to the
    closed-form bound; a frequency gives what its wavelength gives."""
    array = {"n_elements": 6, "radius_m": 0.2, "frequency_hz": 1.5e9}
    rows = trial(array=array)
    wavelength = trial(
        array={"n_elements": 6, "radius_m": 0.2, "wavelength_m": SPEED_OF_LIGHT_M_S / 1.5e9}
    )
    chosen = parameters(array=array)
    assert chosen.array.wavelength_m == SPEED_OF_LIGHT_M_S / 1.5e9
    geometry = build_geometry(chosen)
    theta = geometry.doa[..., 0][geometry.visible]
    theta_crb, phi_crb = uca_crb_deg2(theta, 0.0, 100, chosen.array)
    row = music(rows)
    assert row["doa_crb_theta_deg2"] == pytest.approx(theta_crb, rel=1e-9)
    assert row["doa_crb_phi_deg2"] == pytest.approx(phi_crb, rel=1e-9)
    pd.testing.assert_frame_equal(
        rows.drop(columns="runtime_s"), wavelength.drop(columns="runtime_s")
    )


def test_music_options_reach_the_rejections_and_the_estimates() -> None:
    """A 45-deg horizon rejects every DOA of ``S1`` (59-62 deg); at -14 dB a peak-ratio
    threshold of 1 rejects none as ambiguous (the default half rejects most); another grid
    step or cone changes the estimates."""
    horizon = music(trial(music={"horizon_angle_deg": 45.0}))
    assert horizon["doa_rejected_horizon"] == horizon["doa_count"] > 0
    assert horizon["doa_accepted"] == 0
    faint = {"table1_snr_db": [-14.0]}
    default = music(trial(**faint))
    lenient = music(trial(**faint, music={"peak_ratio_threshold": 1.0}))
    assert default["doa_rejected_ambiguous"] > default["doa_count"] / 2
    assert lenient["doa_rejected_ambiguous"] == 0
    columns = ["doa_accepted", "doa_theta_mse_deg2", "doa_phi_mse_deg2"]
    for options in ({"grid_step": 0.3}, {"cone_half_angle_deg": 50.0}):
        other = music(trial(**faint, music=options))
        assert other[columns].tolist() != default[columns].tolist(), options
        estimator = music_estimator(parameters(music=options).music, parameters().array.array())
        spacing = np.diff(np.unique(estimator.grid[:, 0]))
        assert spacing.min() == pytest.approx(options.get("grid_step", 0.04))
        radius = np.hypot(*estimator.grid.T).max()
        cone = np.radians(options.get("cone_half_angle_deg", 70.0))
        assert np.sin(cone) - spacing.min() * np.sqrt(2) < radius <= np.sin(cone)


def test_the_prior_table_is_the_filters_start() -> None:
    """The EKF starts from ``[prior]``: at the truth's initial attitude its first error is
    small; its first rate error is the prior's rate minus the truth's (the epoch-0 update
    cannot change the rate: no prior correlation); tighter sigmas tighten its first sigma
    and the bound."""
    default = method(trial(), EKF)
    truth = method(trial(prior={"euler_deg": [3.0, -2.0, 2.0]}), EKF)
    error = lambda rows: np.linalg.norm(rows.loc[0, [f"err_{a}_deg" for a in "xyz"]])  # noqa: E731
    assert error(default) > 20.0 and error(truth) < 5.0
    rate = [0.1, -0.2, 0.3]
    moved = method(trial(prior={"rate_deg_s": rate}), EKF)
    first_rate_error = [f"rate_err_{a}_deg_s" for a in "xyz"]
    shift = moved.loc[0, first_rate_error].to_numpy(float) - default.loc[
        0, first_rate_error
    ].to_numpy(float)
    np.testing.assert_allclose(shift, np.subtract(rate, 0.5), atol=1e-9)
    # (from the truth's start: from the paper's, 98 deg off, a 5 deg sigma is flagged by
    # the filter's consistency test)
    near = {"euler_deg": [3.0, -2.0, 2.0]}
    tight = method(trial(prior={**near, "sigma_deg": 5.0, "rate_sigma_deg_s": 0.05}), EKF)
    sigma = [f"sigma_{a}_deg" for a in "xyz"]
    assert tight.loc[0, sigma].max() <= 5.0 and truth.loc[0, sigma].max() > 30.0
    flagged = method(trial(prior={"sigma_deg": 5.0, "rate_sigma_deg_s": 0.05}), EKF)
    assert flagged.loc[0, "reason"].startswith("inconsistent")
    bound = [f"pbound_{a}_deg" for a in "xyz"]
    assert (tight[bound].to_numpy() < default[bound].to_numpy()).all()
    rate_only = method(trial(prior={"rate_sigma_deg_s": 0.05}), EKF)
    assert (rate_only.loc[1:, bound].to_numpy() < default.loc[1:, bound].to_numpy()).all()


def test_the_gyro_and_the_gyro_aided_rows_follow_their_parameters() -> None:
    """``filters``, ``filter_trials`` and ``gyro``: a preset, a table without ``rate_hz``
    (sampled at the epochs) and a near-perfect table, whose MEKF is the most confident
    (from a prior near the truth with 10 deg sigmas: from the paper's 60 deg ones no single
    frame of the one station in view would confirm the MEKF's start)."""
    near = {"euler_deg": [3.0, -2.0, 2.0], "sigma_deg": 10.0}
    aided = {"filter_trials": 1, "filters": ["mekf"], "prior": near}
    assert {"mekf", "bls_yang2014"} <= set(trial(**aided)["method"])
    assert "fg_batch" not in set(trial(**aided)["method"])
    assert not {"mekf", "bls_yang2014"} & set(trial()["method"])
    perfect = {"arw_deg_sqrt_h": 1e-4, "rrw_deg_h_sqrt_h": 1e-4, "turn_on_bias_deg_h": 1e-3}
    assert parameters(gyro=perfect).gyro.rate_hz == 4.0
    runs = {
        "mems": trial(**aided),
        "liu2023": trial(**aided, gyro="liu2023"),
        "perfect": trial(**aided, gyro=perfect),
    }
    settled = {}
    for name, rows in runs.items():
        mekf = method(rows, "mekf")
        settled[name] = mekf.loc[mekf["phase"] == "settled", "sigma_x_deg"].mean()
    assert settled["perfect"] < settled["mems"] != settled["liu2023"]


def test_rows_follow_the_pass_row_and_table_parameters() -> None:
    """Duration, step, row step, settling time, the EKFs' ``Q`` values, and the settings of
    Tables 1 and 2 (``snr_db``, ``snapshots`` set the rows' CRBs)."""
    rows = trial(
        step_s=0.5, duration_s=40.0, row_step_s=2.0, settle_s=10.0, process_noise=[1e-9, 1e-10]
    )
    ekf = method(rows, "ekf_yang2014_q1e-10")
    np.testing.assert_array_equal(ekf["t_s"], np.arange(0.0, 40.0, 2.0))
    assert (ekf["phase"] == np.where(ekf["t_s"] < 10.0, "converging", "settled")).all()
    assert {"ekf_yang2014_q1e-09", "rts_yang2014_q1e-10"} <= set(rows["method"])
    assert (
        music(rows)["doa_count"]
        == build_geometry(parameters(step_s=0.5, duration_s=40.0)).visible.sum()
    )
    tables = {
        "table1_snr_db": [-3.0, 3.0],
        "table1_snapshots": 50,
        "table2_snr_db": 3.0,
        "table2_snapshots": [5, 50],
    }
    settings = grid(parameters(**tables).model_dump(mode="json"))
    assert [(s["snr_db"], s["snapshots"]) for s in settings] == [(-3.0, 50), (3.0, 50), (3.0, 5)]
    geometry = build_geometry(parameters())
    theta = geometry.doa[..., 0][geometry.visible]
    row = music(trial(**tables))
    crb = uca_crb_deg2(theta, -3.0, 50, parameters().array)
    assert [row["doa_crb_theta_deg2"], row["doa_crb_phi_deg2"]] == pytest.approx(crb, rel=1e-9)


BAD_VALUES = [
    "[array]\nn_elements = 2\n",
    "[array]\nwavelength_m = 0.15\nfrequency_hz = 1e9\n",
    "[music]\ngrid_step = 0.5\n",
    "[music]\nhorizon_angle_deg = 95.0\n",
    "stations = []\n",
    "[[stations]]\nname = 'A'\nlatitude_deg = 95.0\nlongitude_deg = 0.0\n",
    "[[stations]]\nname = 'A'\nlatitude_deg = 0.0\nlongitude_deg = 0.0\n"
    "[[stations]]\nname = 'A'\nlatitude_deg = 1.0\nlongitude_deg = 0.0\n",
    "[[stations]]\nlatitude_deg = 0.0\nlongitude_deg = 0.0\n",
    "min_elevation_deg = 90.0\n",
    "[attitude]\ninertia_kg_m2 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 5.0]]\n",
    "[attitude]\ninertia_kg_m2 = [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n",
    "[attitude]\ninertia_kg_m2 = [[1.0, 0.0], [0.0, 1.0]]\n",
    "[attitude]\nwheel_momentum_nms = [0.0, 1.0]\n",
    "[attitude]\ninitial_euler_deg = [nan, 0.0, 0.0]\n",
    "[prior]\nsigma_deg = 0.0\n",
    "[prior]\neuler_deg = ['50', 50, 50]\n",
    "gyro = 'navgrade'\n",
    "[gyro]\nrate_hz = 10.0\n",
    "start_utc = 'yesterday'\n",
    "[orbit]\ntype = 'tle'\nline1 = '1 garbage'\nline2 = '2 garbage'\n",
    "[orbit]\ntype = 'circular'\naltitude_km = 50.0\n",
    "row_step_s = 0.1\n",
    "process_noise = []\n",
    "process_noise = [1e-9, 0.0]\n",
    "table2_snapshots = [10, 0]\n",
    "filters = ['ukf']\n",
    "initial_sigma_deg = 60.0\n",
]


@pytest.mark.parametrize("text", BAD_VALUES)
def test_bad_values_exit_2_with_one_line_each(tmp_path: Path, text: str) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(text)
    result = CliRunner().invoke(
        app, ["run", "doa-ground", "--quick", "--config", str(config), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert lines and all(line.startswith(f"error: {config}") for line in lines), lines
    assert "Traceback" not in result.output
    assert not (tmp_path / "o").exists()


def test_every_bad_value_is_reported_with_its_key_path() -> None:
    overrides = {
        "stations": [THREE[0], {**THREE[1], "latitude_deg": -100.0}],
        "array": {"n_elements": 1},
        "attitude": {"initial_euler_deg": [1.0, 2.0]},
        "gyro": {"rate_hz": 1.0},
        "row_step_s": 0.01,
    }
    with pytest.raises(ConfigError) as raised:
        resolve_parameters(EXPERIMENT, overrides=overrides)
    text = "\n".join(raised.value.problems)
    assert len(raised.value.problems) == 5, text
    for path in (
        "stations[1].latitude_deg = -100.0",
        "array.n_elements = 1",
        "attitude.initial_euler_deg = [1.0, 2.0]",
        "gyro = {'rate_hz': 1.0}",
        "row_step_s = 0.01",
    ):
        assert path in text
    assert "rate_hz must be 1 / step_s = 4" in text


def test_the_documented_configuration_is_valid() -> None:
    """``docs/doa.md``'s three-station, 8-element example loads as written."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "doa.md").read_text()
    block = text.split("### Your own set-up")[1].split("```toml\n")[1].split("```")[0]
    chosen = DoaGroundParameters.model_validate(tomllib.loads(block))
    assert [s.name for s in chosen.stations] == ["Kiruna", "Svalbard", "Troll"]
    assert chosen.array.array().n_elements == 8
    assert chosen.array.wavelength_m == SPEED_OF_LIGHT_M_S / 1.5e9
