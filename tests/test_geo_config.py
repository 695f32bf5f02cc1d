"""geo-snr-stations from its parameters (Pimienta-Penalver and Crassidis): every parameter
overridden on a short pass and seen in the rows, other station sets and beamwidths, and bad
configurations refused with exit code 2."""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
import pytest
from astropy.time import Time
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.config import describe, flat_items, resolve_parameters
from attopt.experiments.config.loading import deep_merge
from attopt.experiments.environment.orbit import ecef_to_eci_matrices
from attopt.experiments.geo_snr_stations.experiment import EXPERIMENT, trial
from attopt.experiments.geo_snr_stations.parameters import EQ27_QUATERNION, GARUDA1_TLE
from attopt.experiments.sweep.tasks import labelled_rows
from attopt.formulations.conventions import attitude_from_shuster_quaternion
from tests.report_tables import table

BASE = {
    "duration_s": 300.0,
    "step_s": 60.0,
    "manoeuvre": [False],
    "methods": ["lsq"],
    "filters": [],
}
"""A short pass (5 epochs) with the cheapest method; each case adds what it checks."""
FILTERS = {"filters": ["usque"]}
NADIR = {"attitude": {"initial": {"type": "nadir"}}}
THREE_STATIONS = [
    {"name": "Surabaya", "latitude_deg": -7.28252, "longitude_deg": 112.833, "height_m": 5.0},
    {"name": "General Santos", "latitude_deg": 6.086357, "longitude_deg": 125.1304},
    {"name": "Labuan", "latitude_deg": 5.298122, "longitude_deg": 115.207, "height_m": 76.0},
]
"""Three of Table 2 (General Santos at the default height 0 m instead of 15 m)."""
Z = np.array([0.0, 0.0, 1.0])


def _tle_line(line: str) -> str:
    """``line`` with its modulo-10 checksum recomputed (the TLE format's last column)."""
    total = sum(int(c) if c.isdigit() else c == "-" for c in line[:68])
    return line[:68] + str(total % 10)


SHIFTED_TLE = (
    GARUDA1_TLE[0],
    _tle_line(GARUDA1_TLE[1].replace(" 176.2140 ", " 178.2140 ")),
)
"""Garuda-1 two degrees further along its orbit (mean anomaly), 125.0 deg E."""


@functools.cache
def _rows(document: str, manoeuvre: bool = False) -> pd.DataFrame:
    parameters = resolve_parameters(EXPERIMENT, overrides=json.loads(document))
    settings = EXPERIMENT.grid(parameters.model_dump(mode="json"))
    (setting,) = [s for s in settings if s["manoeuvre"] == manoeuvre]
    return labelled_rows(trial(setting, np.random.SeedSequence(0)), setting, 0, 0)


def rows(*overrides: Mapping[str, Any], manoeuvre: bool = False) -> pd.DataFrame:
    """The trial rows (seed 0) of :data:`BASE` updated by ``overrides`` in turn."""
    document: dict[str, Any] = dict(BASE)
    for override in overrides:
        document = deep_merge(document, override)
    if manoeuvre:
        document["manoeuvre"] = [False, True]
    return _rows(json.dumps(document, sort_keys=True), manoeuvre)


def method(frame: pd.DataFrame, label: str) -> pd.DataFrame:
    return frame[frame["method"] == label].reset_index(drop=True)


def quaternions(frame: pd.DataFrame, kind: str) -> Rotation:
    return Rotation.from_quat(frame[[f"q_{kind}_{c}" for c in "xyzw"]].to_numpy())


def sub_satellite_longitude_deg(frame: pd.DataFrame, start_utc: str) -> float:
    """The ECEF longitude of minus the true boresight at t = 0 (the sub-satellite point of a
    beam at nadir)."""
    boresight = quaternions(frame, "true")[0].inv().apply(Z)
    ecef = ecef_to_eci_matrices(Time([start_utc], scale="utc"))[0].T @ -boresight
    return float(np.degrees(np.arctan2(ecef[1], ecef[0])))


def pointing_magnitude(frame: pd.DataFrame) -> np.ndarray:
    return np.hypot(frame["err_x_deg"], frame["err_y_deg"]).to_numpy()


DEFAULT_STATIONS = np.array([4, 4, 4, 4, 4])
"""lsq's stations on the base pass: Surabaya, Darwin, General Santos, Labuan (docs/geo.md)."""
DETECTOR = {"duration_s": 600.0, "filters": ["usque_detect"], "false_alarm": 0.999}
"""10 epochs with a detector that restarts on false alarms (none at the default 1e-6)."""
MANOEUVRE = {"angle_deg": 10.0, "start_s": 60.0, "duration_s": 120.0}
MANADO = {"name": "Manado", "latitude_deg": 1.49, "longitude_deg": 124.84, "height_m": 10.0}

OVERRIDES: dict[str, dict[str, Any]] = {
    "duration": {"duration_s": 240.0},
    "step": {"step_s": 30.0},
    "start": {**NADIR, "start_utc": "2015-11-30T21:00:00"},
    "tle": {
        **NADIR,
        "broadcaster": {"orbit": {"type": "tle", "line1": SHIFTED_TLE[0], "line2": SHIFTED_TLE[1]}},
    },
    "geostationary": {
        **NADIR,
        "broadcaster": {"orbit": {"type": "geostationary", "longitude_deg": 118.5}},
    },
    "power": {"broadcaster": {"transmit_power_w": 12.0}},  # -30 dB
    "frequency": {"broadcaster": {"frequency_hz": 3.1e9}},  # half the beamwidth
    "noise_bandwidth": {"broadcaster": {"noise_bandwidth_hz": 2.4e6}},  # -30 dB
    "diameter": {"broadcaster": {"antenna": {"diameter_m": 24.0}}},
    "efficiency": {"broadcaster": {"antenna": {"efficiency": 0.00055}}},  # -30 dB
    "roll_off": {"broadcaster": {"antenna": {"roll_off_db": 20.0}}},
    "beamwidth": {"broadcaster": {"antenna": {"beamwidth_deg": 3.0}}},
    "lobe_edge": {"broadcaster": {"antenna": {"lobe_edge_deg": 2.0}}},
    "temperature": {"receiver": {"temperature_k": 38_000.0}},  # -30 dB
    "receiver_gain": {"receiver": {"gain_dbi": -30.0}},
    "threshold": {"receiver": {"detection_threshold_db": 30.0}},  # above Darwin's 24 dB
    "snr_sigma": {"receiver": {"snr_sigma_db": 1.48e-4}},
    "three_stations": {"stations": THREE_STATIONS},
    "moved_station": {
        "stations": [*THREE_STATIONS[:2], {**THREE_STATIONS[2], "height_m": 2_000.0}]
    },
    "four_stations": {"stations": [*THREE_STATIONS, MANADO]},
    "quaternion": {"attitude": {"initial": {"type": "quaternion", "components": [0, 0, 0, 1.0]}}},
    "nadir_yaw": {"attitude": {"initial": {"type": "nadir", "yaw_deg": 30.0}}},
    "slew": {"attitude": {"slew_rate_deg_h": 11.0}},
    "manoeuvre": {"manoeuvre": [False, True], "attitude": {"manoeuvre": MANOEUVRE}},
    "methods": {"methods": ["cone", "nlse"]},
    "filters": {"filters": ["mekf", "rts", "fg_online", "ekf_yang2014"]},
    "filter_stations": {
        **FILTERS,
        "methods": ["cone"],
        "filter_stations": ["Surabaya", "Darwin", "General Santos", "Labuan"],
    },
    "initial_sigma": {**FILTERS, "initial_sigma_deg": 1.0},
    "arw": {**FILTERS, "assumed_rate": {"arw_deg_sqrt_h": 10.0}},
    "rrw": {**FILTERS, "assumed_rate": {"rrw_deg_h_sqrt_h": 100.0}},
    "rate_sigma": {**FILTERS, "assumed_rate": {"initial_sigma_deg_h": 100.0}},
    "window": {"filters": ["usque_detect"], "detection_window_s": 240.0},
    "false_alarm": DETECTOR,
    "max_restarts": {**DETECTOR, "restart": {"max_restarts": 1}},
    "restart_yaw": {**DETECTOR, "restart": {"yaw_sigma_deg": 40.0}},
    "restart_boresight": {**DETECTOR, "restart": {"boresight_sigma_deg": 1e-5}},
    "restart_rate": {**DETECTOR, "restart": {"rate_sigma_deg_h": 2_000.0}},
    "estimator_options": {
        **FILTERS,
        "estimator_options": {"usque": {"filter": {"max_attitude_sigma": 1e-9}}},
    },
}
"""Each check's overrides of :data:`BASE` (flat ``{name: document}``, so that
:func:`test_every_parameter_is_overridden` sees exactly what the checks use)."""


def case(name: str, manoeuvre: bool = False) -> pd.DataFrame:
    """The rows of override ``name``."""
    return rows(OVERRIDES[name], manoeuvre=manoeuvre)


def lsq_stations(frame: pd.DataFrame) -> np.ndarray:
    return method(frame, "lsq")["n_stations"].to_numpy()


def check_duration() -> None:
    assert method(case("duration"), "lsq")["t_s"].tolist() == [0, 60, 120, 180]


def check_step() -> None:
    assert method(case("step"), "lsq")["t_s"].tolist() == [30.0 * k for k in range(10)]


def check_start() -> None:
    """Four hours later Garuda-1 is still over 123 E (geostationary) and the nadir at the
    start has turned with the Earth by 4 h x 15.04 deg/h in ECI."""
    later, start = case("start"), OVERRIDES["start"]["start_utc"]
    assert set(later["start_utc"]) == {start}
    assert sub_satellite_longitude_deg(later, start) == pytest.approx(123.0, abs=0.05)
    boresights = [quaternions(f, "true")[0].inv().apply(Z) for f in (later, rows(NADIR))]
    angle = np.degrees(np.arccos(np.clip(boresights[0] @ boresights[1], -1.0, 1.0)))
    assert angle == pytest.approx(4.0 * 15.041, abs=0.1)


def check_tle() -> None:
    start = EXPERIMENT.parameters["start_utc"]
    assert sub_satellite_longitude_deg(case("tle"), start) == pytest.approx(125.0, abs=0.05)
    assert sub_satellite_longitude_deg(rows(NADIR), start) == pytest.approx(123.0, abs=0.05)


def check_geostationary() -> None:
    frame, start = case("geostationary"), EXPERIMENT.parameters["start_utc"]
    assert sub_satellite_longitude_deg(frame, start) == pytest.approx(118.5, abs=1e-9)
    assert method(frame, "lsq")["valid"].all()


@pytest.mark.parametrize(
    "name",
    [
        "power",
        "frequency",
        "noise_bandwidth",
        "diameter",
        "efficiency",
        "roll_off",
        "lobe_edge",
        "temperature",
        "receiver_gain",
        "threshold",
    ],
)
def test_a_weaker_link_is_heard_by_fewer_stations(name: str) -> None:
    """30 dB less power, gain or noise figure, a narrower or steeper or shorter main lobe,
    a higher threshold: Darwin (24 dB at the start, the farthest) no longer hears."""
    assert (lsq_stations(rows()) == DEFAULT_STATIONS).all()
    assert (lsq_stations(case(name)) < DEFAULT_STATIONS).all()


def check_beamwidth() -> None:
    assert (lsq_stations(case("beamwidth")) > DEFAULT_STATIONS).all()


def check_snr_sigma() -> None:
    """The noise, and with it the error and the Cramer-Rao bound, scale with the sigma."""
    base, quiet = method(rows(), "lsq"), method(case("snr_sigma"), "lsq")
    np.testing.assert_allclose(quiet["bound_x_deg"], base["bound_x_deg"] / 100.0, rtol=1e-9)
    np.testing.assert_allclose(
        pointing_magnitude(quiet), pointing_magnitude(base) / 100.0, rtol=1e-3
    )


def check_stations() -> None:
    """Three stations, then one of them 2 km higher, then a fourth added."""
    three = case("three_stations")
    assert (three["n_stations"] == 3).all() and three["valid"].all()
    higher = case("moved_station")
    assert (higher["n_stations"] == 3).all()
    assert not np.allclose(pointing_magnitude(higher), pointing_magnitude(three), rtol=1e-6)
    assert (case("four_stations")["n_stations"] == 4).all()


def check_quaternion() -> None:
    """A 30 deg yaw about the boresight from eq. 27's: the truth follows, the SNRs (and so
    the size of the pointing error) do not; the identity gives the identity."""
    initial = attitude_from_shuster_quaternion(EQ27_QUATERNION)
    yawed = Rotation.from_rotvec(np.radians(30.0) * Z) * initial
    shuster = yawed.inv().as_quat().tolist()
    override = {"attitude": {"initial": {"type": "quaternion", "components": shuster}}}
    frame = method(rows(override), "lsq")
    assert quaternions(frame, "true")[0].approx_equal(yawed, atol=1e-12)
    np.testing.assert_allclose(
        pointing_magnitude(frame), pointing_magnitude(method(rows(), "lsq")), rtol=1e-6
    )
    identity = quaternions(case("quaternion"), "true")[0]
    assert identity.magnitude() == pytest.approx(0.0, abs=1e-15)


def check_nadir_yaw() -> None:
    turn = quaternions(case("nadir_yaw"), "true")[0] * quaternions(rows(NADIR), "true")[0].inv()
    np.testing.assert_allclose(turn.as_rotvec(), [0.0, 0.0, np.radians(30.0)], atol=1e-12)


def check_slew() -> None:
    """``A(t) = A_0 R_z(Omega t)^T``: 10 deg/h more slew turns the truth by 10 deg/h x t."""
    fast = quaternions(case("slew"), "true")
    turned = (fast * quaternions(rows(), "true").inv()).magnitude()
    np.testing.assert_allclose(np.degrees(turned), 10.0 * np.arange(5) / 60.0, atol=1e-9)


def check_manoeuvre() -> None:
    """A 10 deg turn from 60 s over 120 s: none before, half at 120 s, all from 180 s."""
    on, off = case("manoeuvre", manoeuvre=True), case("manoeuvre")
    assert set(on["manoeuvre"]) == {True} and set(off["manoeuvre"]) == {False}
    turned = quaternions(on, "true") * quaternions(off, "true").inv()
    np.testing.assert_allclose(
        np.degrees(turned.magnitude()), [0.0, 0.0, 5.0, 10.0, 10.0], atol=1e-9
    )


def check_methods() -> None:
    frame = case("methods")
    assert list(dict.fromkeys(frame["method"])) == ["cone", "nlse"]
    assert frame["valid"].all()


def check_filters() -> None:
    """Other pass estimators of the registry; one that cannot run here gives invalid rows."""
    frame = case("filters")
    labels = ["lsq", "mekf", "rts", "fg_online", "ekf_yang2014"]
    assert list(dict.fromkeys(frame["method"])) == labels
    assert frame[frame["method"] != "ekf_yang2014"]["valid"].all()
    failed = method(frame, "ekf_yang2014")
    assert not failed["valid"].any() and failed["reason"].str.contains("dynamics").all()


def check_filter_stations() -> None:
    frame = case("filter_stations")
    assert (frame["n_stations"] == 4).all() and frame["valid"].all()


def check_initial_sigma() -> None:
    """Yaw is unobserved: the filter's yaw sigma stays near its prior's."""
    for frame, sigma in ((rows(FILTERS), 5.0), (case("initial_sigma"), 1.0)):
        assert method(frame, "usque")["sigma_z_deg"].iloc[0] == pytest.approx(sigma, rel=0.02)


def check_assumed_rate() -> None:
    """More rate noise, more yaw uncertainty by the end of the pass."""
    last = method(rows(FILTERS), "usque")["sigma_z_deg"].iloc[-1]
    for name in ("arw", "rrw", "rate_sigma"):
        assert method(case(name), "usque")["sigma_z_deg"].iloc[-1] > 1.001 * last, name


def check_detection() -> None:
    """The window sets the epochs without a p-value; false alarms at 0.999 restart the filter
    without a manoeuvre, none at the default."""
    quiet = method(rows({"filters": ["usque_detect"]}), "usque_detect")
    assert not quiet["detected"].any() and quiet["p_value"].isna().sum() == 2  # 3 epochs
    assert method(case("window"), "usque_detect")["p_value"].isna().sum() == 3  # 4 epochs
    assert method(case("false_alarm"), "usque_detect")["detected"].any()


def check_restart() -> None:
    """After a (false-alarm) restart the filter starts from [restart]'s sigmas (the first
    prior from its boresight sigma too), at most max_restarts times."""
    base = method(case("false_alarm"), "usque_detect")
    restarts = np.flatnonzero(base["detected"])
    assert restarts.size >= 2
    assert method(case("max_restarts"), "usque_detect")["detected"].sum() == 1
    k = restarts[0]
    assert base["sigma_z_deg"][k] == pytest.approx(20.0, rel=0.02)
    wide = method(case("restart_yaw"), "usque_detect")
    assert wide["sigma_z_deg"][k] == pytest.approx(40.0, rel=0.02)
    tight = method(case("restart_boresight"), "usque_detect")
    assert tight["sigma_x_deg"][k] < 1e-5 < base["sigma_x_deg"][k]
    assert tight["sigma_x_deg"][0] < 1e-5 < base["sigma_x_deg"][0]  # the first prior's too
    rate = method(case("restart_rate"), "usque_detect")
    # a wider rate sigma lets the yaw sigma grow further between the restarts (to 72 deg;
    # 20 deg with the default), until an epoch's exceeds the 90 deg validity limit
    assert rate["sigma_z_deg"].max() > 1.5 * base["sigma_z_deg"].max()


def check_estimator_options() -> None:
    """``[estimator_options.usque.filter]`` reaches USQUE: no attitude within a 1e-9 rad
    sigma, so every epoch is flagged (valid with the trial's own filter options)."""
    assert not method(case("estimator_options"), "usque")["valid"].any()
    assert method(rows(FILTERS), "usque")["valid"].all()


CHECKS: dict[str, Callable[[], None]] = {
    name.removeprefix("check_"): value
    for name, value in dict(globals()).items()
    if name.startswith("check_")
}


@pytest.mark.parametrize("name", sorted(CHECKS))
def test_the_rows_reflect_the_parameter(name: str) -> None:
    CHECKS[name]()


def _leaf(path: str) -> str:
    """A schema leaf's path; ``estimator_options`` is one free-form table (its keys are
    the registry's estimators and their fields)."""
    if path.startswith("estimator_options."):
        return "estimator_options"
    return re.sub(r"\[\d+\]", "[]", re.sub(r"\(type=[^)]*\)", "", path))


def test_every_parameter_is_overridden() -> None:
    """Each leaf of the schema (every variant of the tagged tables) is overridden by a check,
    and every override is a valid config."""
    leaves = {_leaf(p.path) for p in describe(EXPERIMENT.schema)}
    documents = [*OVERRIDES.values(), BASE]
    overridden = {_leaf(path) for document in documents for path in flat_items(document)}
    assert leaves - overridden == set()
    for document in OVERRIDES.values():
        resolve_parameters(EXPERIMENT, overrides=deep_merge(BASE, document))


def test_three_stations_run_from_toml_and_the_report_follows(tmp_path) -> None:
    """``attopt run`` with a 3-station config: the rows, config.toml and the report's station
    table follow it (a wider beam: ``check_beamwidth``)."""
    stations = "".join(
        f'[[stations]]\nname = "{s["name"]}"\nlatitude_deg = {s["latitude_deg"]}\n'
        f"longitude_deg = {s['longitude_deg']}\n"
        for s in THREE_STATIONS
    )
    config = tmp_path / "three.toml"
    config.write_text(
        "duration_s = 300.0\nstep_s = 60.0\nmanoeuvre = [false]\n"
        'methods = ["cone", "lsq"]\nfilters = ["usque_detect"]\n' + stations
    )
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app,
        [
            *("run", "geo-snr-stations", "--config", str(config), "--out", str(out)),
            *("--trials", "1", "--workers", "1", "--no-progress"),
        ],
    )
    assert result.exit_code == 0, result.output
    stored = pd.concat([pd.read_parquet(f) for f in sorted((out / "rows").glob("*.parquet"))])
    assert (stored["n_stations"] == 3).all() and stored["valid"].all()
    assert "General Santos" in (out / "config.toml").read_text()
    report = (out / "report.md").read_text()
    assert table(report, "Stations")["station"].tolist() == [s["name"] for s in THREE_STATIONS]


BAD_VALUES = """
start_utc = "yesterday"
step_s = -1.0
methods = ["cone", "davenport"]
filters = ["quest"]
[broadcaster]
transmit_power_w = 0.0
[broadcaster.orbit]
type = "molniya"
[broadcaster.antenna]
efficiency = 1.5
beamwidth_deg = -2.0
[receiver]
snr_sigma_db = "small"
[attitude.initial]
type = "quaternion"
components = [0.0, 0.0, 0.0]
[[stations]]
name = "Nowhere"
latitude_deg = 95.0
longitude_deg = 0.0
"""


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            BAD_VALUES,
            [
                "start_utc = 'yesterday'",
                "step_s = -1.0",
                "methods[1] = 'davenport'",
                "filters[0] = 'quest'",
                "broadcaster.transmit_power_w = 0.0",
                "broadcaster.orbit",
                "broadcaster.antenna.efficiency = 1.5",
                "broadcaster.antenna.beamwidth_deg = -2.0",
                "receiver.snr_sigma_db = 'small'",
                "attitude.initial.components = [0.0, 0.0, 0.0]",
                "stations[0].latitude_deg = 95.0",
            ],
        ),
        ('filter_stations = ["Surabaya", "Labuan", "Perth"]\n', ["['Perth'] are not stations"]),
        ("duration_s = 10.0\n", ["must hold two epochs"]),
        ('methods = ["lsq", "lsq"]\n', ["unique across methods and filters: ['lsq']"]),
        (
            '[[stations]]\nname = "A"\nlatitude_deg = 0.0\nlongitude_deg = 0.0\n' * 2,
            ["station names must be unique: ['A']"],
        ),
        ("[broadcaster.antenna]\nlobe_edge_deg = 95.0\n", ["lobe_edge_deg = 95.0"]),
    ],
    ids=["values", "filter_stations", "duration", "methods", "station_names", "lobe_edge"],
)
def test_bad_configs_exit_2_with_one_line_each(tmp_path, text: str, expected: list[str]) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(text)
    result = CliRunner().invoke(
        app, ["run", "geo-snr-stations", "--config", str(config), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert all(line.startswith(f"error: {config}: ") for line in lines)
    for fragment in expected:
        assert any(fragment in line for line in lines), (fragment, lines)
    assert not (tmp_path / "o").exists()
