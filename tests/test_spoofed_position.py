"""Aircraft that broadcast a wrong position (``[traffic.spoofer]``) and the snapshot SNR
solvers' fault detection and exclusion (:mod:`attopt.solvers.snr.exclusion`).

The passes are those of ``tests/test_adsb_config.py`` (12 s at 2 s, 600 flights, off
the east coast of North America: about 90 messages per epoch on antenna 2, 5 on
antenna 1); the synthetic epochs those of ``tests/test_snr_solvers.py``.
"""

from __future__ import annotations

import functools
import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from attopt.experiments.adsb_snr.experiment import (
    EXPERIMENT,
    method_estimators,
    snr_snapshots,
    trial_pass,
)
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry
from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.config.loading import deep_merge
from attopt.experiments.environment.traffic import geodetic_normals, horizontal_offsets_km
from attopt.experiments.metrics import error_columns
from attopt.solvers.snapshot_sequence import residual_test
from attopt.solvers.snr.exclusion import exclusion_statistics, parity_projection
from attopt.solvers.snr.fit import Residuals
from tests.test_adsb_config import SEED, TINY
from tests.test_snr_solvers import SOLVERS, TRUTH, _epoch, _geometry, _snapshots

QUANTILE = 21.107
"""The chi-square(3) 1 - 1e-4 quantile of the integrity statistic."""
SNAPSHOT = ["deterministic", "nlse", "nlp", "nlp_truncated"]
ONE_STEP = ["nlse", "nlp", "nlp_truncated"]
SPOOFED = 27
"""An aircraft that antenna 2 receives at every epoch of the pass."""
FAR = {"aircraft": [SPOOFED], "offset_km": 1000.0, "azimuth_deg": 90.0}
"""A spoofed position far enough off for the residual test to see it at some epochs."""
runner = CliRunner()


@functools.cache
def _pass(document: str):
    parameters = resolve_parameters(EXPERIMENT, overrides=deep_merge(TINY, json.loads(document)))
    return parameters, *trial_pass(parameters, SEED)


def spoofed_pass(spoofer: dict | None):
    """Parameters, noise-free and noisy pass of trial 0 with ``spoofer`` (``None``: none)."""
    traffic = {} if spoofer is None else {"traffic": {"spoofer": spoofer}}
    return _pass(json.dumps(traffic, sort_keys=True))


# --- the parameter ------------------------------------------------------------------------------


@settings(max_examples=50, deadline=None)
@given(
    latitude=st.floats(-80.0, 80.0),
    longitude=st.floats(-180.0, 180.0),
    azimuth=st.floats(0.0, 2.0 * np.pi),
    distance=st.floats(0.1, 2000.0),
)
def test_a_horizontal_offset_has_its_length_and_azimuth(latitude, longitude, azimuth, distance):
    """The displacement is ``distance`` long, normal to the geodetic normal, and its north
    and east components are ``cos`` and ``sin`` of the azimuth."""
    lat, lon = np.radians(latitude), np.radians(longitude)
    normal = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    offset = horizontal_offsets_km(normal, azimuth, distance)
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    assert np.linalg.norm(offset) == pytest.approx(distance, rel=1e-12)
    assert abs(offset @ normal) < 1e-9 * distance
    assert offset @ north == pytest.approx(distance * np.cos(azimuth), abs=1e-9 * distance)
    assert offset @ east == pytest.approx(distance * np.sin(azimuth), abs=1e-9 * distance)


@pytest.mark.parametrize(
    "spoofer",
    [
        {},
        {"aircraft": 3, "offset_km": 200.0, "start_s": 4.0, "duration_s": 4.0},
        {"aircraft": [SPOOFED, 401], "offset_km": 10.0, "azimuth_deg": 30.0},
    ],
)
def test_the_spoofer_moves_only_its_aircrafts_broadcast_positions_by_its_offset(spoofer):
    """Only the rows of the spoofed aircraft inside the window change, each position by
    ``offset_km`` horizontally (at ``azimuth_deg`` when given), and the epochs carry the
    lines of sight and powers of the broadcast position; the SNRs, what is received and
    the truth are those of the pass without a spoofer."""
    parameters, scenario, noisy = spoofed_pass(spoofer)
    _, clean_scenario, clean = spoofed_pass(None)
    decoded = noisy.decoded
    expected_count = 1 if "aircraft" not in spoofer else spoofer["aircraft"]
    if isinstance(expected_count, list):
        assert decoded.spoofed.tolist() == expected_count
    else:
        assert decoded.spoofed.size == expected_count
    window = parameters.traffic.spoofer.active(scenario.t[scenario.epoch_index])
    rows = np.isin(scenario.aircraft, decoded.spoofed) & window
    assert rows.any()
    offset = decoded.aircraft_ecef_km - scenario.aircraft_ecef_km
    moved = np.any(offset != 0.0, axis=1)
    assert np.array_equal(moved, rows)
    expected_km = parameters.traffic.spoofer.offset_km
    np.testing.assert_allclose(np.linalg.norm(offset[rows], axis=1), expected_km, rtol=1e-9)
    traffic = build_adsb_geometry(parameters).traffic
    normal = geodetic_normals(
        traffic, scenario.t[scenario.epoch_index[rows]], scenario.aircraft[rows]
    )
    np.testing.assert_allclose(np.sum(offset[rows] * normal, axis=1), 0.0, atol=1e-9 * expected_km)
    if "azimuth_deg" in spoofer:
        north = horizontal_offsets_km(normal, 0.0, 1.0)
        cosine = np.sum(offset[rows] * north, axis=1) / expected_km
        np.testing.assert_allclose(cosine, np.cos(np.radians(spoofer["azimuth_deg"])), atol=1e-9)
    assert not np.any(decoded.los_orbit[~rows] != scenario.los_orbit[~rows])
    assert np.all(np.any(decoded.los_orbit[rows] != scenario.los_orbit[rows], axis=1))
    assert np.array_equal(noisy.measured_db, clean.measured_db)
    assert np.array_equal(noisy.true_snr_db, clean.true_snr_db)
    assert np.array_equal(scenario.truth.as_quat(), clean_scenario.truth.as_quat())
    received = np.flatnonzero(noisy.received)
    stacked = np.concatenate([epoch.los_orbit for epoch in noisy.epochs])
    assert np.array_equal(stacked, decoded.los_orbit[received])
    assert np.array_equal(
        np.concatenate([e.p0_dbw for e in noisy.epochs]), decoded.p0_dbw[received]
    )


def test_a_pass_without_a_spoofer_decodes_the_true_geometry():
    """No spoofer: the epochs carry the true lines of sight and powers."""
    _, scenario, noisy = spoofed_pass(None)
    assert noisy.decoded.spoofed.size == 0
    assert noisy.decoded.los_orbit is scenario.los_orbit
    assert noisy.decoded.p0_dbw is scenario.p0_dbw


def test_a_spoofer_outside_the_pass_leaves_every_row_unchanged():
    """A spoofer whose window starts after the pass draws from its own stream alone: every
    row of the trial (snapshot methods and a filter) is bitwise the one without it."""
    estimators = {"methods": SNAPSHOT, "filters": ["mekf_snr"], "gyros": ["mems"]}
    rows = []
    for spoofer in (None, {"aircraft": 2, "start_s": 100.0}):
        traffic = {} if spoofer is None else {"traffic": {"spoofer": spoofer}}
        parameters = resolve_parameters(
            EXPERIMENT, overrides=deep_merge(TINY, {**estimators, **traffic})
        )
        setting = EXPERIMENT.grid(parameters.model_dump(mode="json"))[0]
        rows.append(EXPERIMENT.trial(setting, SEED).drop(columns="runtime_s"))
    assert rows[0].equals(rows[1])


def test_the_spoofer_table_is_listed_and_a_config_with_it_loads(tmp_path):
    """``attopt show`` lists the table; the starter config and one with the table load."""
    shown = runner.invoke(app, ["show", "adsb-snr"])
    assert shown.exit_code == 0
    for key in ("aircraft", "offset_km", "azimuth_deg", "start_s", "duration_s"):
        assert f"traffic.spoofer(table).{key}" in shown.output
    starter = runner.invoke(app, ["show", "adsb-snr", "--toml"])
    config = tmp_path / "spoofed.toml"
    config.write_text(starter.output + "\n[traffic.spoofer]\naircraft = [3, 5]\noffset_km = 20.0\n")
    parameters = resolve_parameters(EXPERIMENT, config=config)
    assert parameters.traffic.spoofer.aircraft == [3, 5]
    assert parameters.traffic.spoofer.offset_km == 20.0


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("aircraft = 0", "at least 1"),
        ("aircraft = [3, 3]", "distinct fleet indices"),
        ("aircraft = [10000]", "fleet indices below 10000"),
        ("offset_km = -5.0", "traffic.spoofer.offset_km"),
    ],
)
def test_bad_spoofer_values_exit_2(tmp_path, table, message):
    config = tmp_path / "bad.toml"
    config.write_text(f"[traffic.spoofer]\n{table}\n")
    result = runner.invoke(
        app, ["run", "adsb-snr", "--config", str(config), "--out", str(tmp_path / "out")]
    )
    assert result.exit_code == 2, result.output
    assert message in result.output


# --- the snapshot solvers on a spoofed pass -----------------------------------------------------


def _solved(spoofer: dict, fault_exclusion: bool):
    """Per snapshot method: its track of the spoofed pass and the NEES of each epoch."""
    parameters, scenario, noisy = spoofed_pass(spoofer)
    snapshots = snr_snapshots(noisy.epochs)
    solved = {}
    for label, solver in method_estimators(parameters).items():
        track = replace(solver, fault_exclusion=fault_exclusion).solve_sequence(snapshots)
        solved[label] = (track, error_columns(track, scenario.truth)["nees"])
    return solved


def test_the_one_step_methods_exclude_the_spoofed_aircraft_and_stay_consistent():
    """An aircraft 1000 km off: where a method excludes a transmitter it is the spoofed
    aircraft, at least one epoch is repaired so, and no valid one-step epoch has a NEES
    beyond the quantile; without the exclusion those epochs are flagged."""
    with_exclusion = _solved(FAR, True)
    without = _solved(FAR, False)
    repaired = 0
    for label in SNAPSHOT:
        track, nees = with_exclusion[label]
        excluded = track.diagnostics["excluded_transmitter"]
        done = np.isfinite(excluded)
        assert np.all(excluded[done] == SPOOFED), label
        assert np.all(track.valid[done]) and np.all(track.diagnostics["n_excluded"][done] == 1)
        flagged = without[label][0].reason[done]
        assert all(reason.startswith("model mismatch") for reason in flagged), label
        repaired += int(done.sum())
        if label in ONE_STEP:
            assert np.mean(nees[track.valid] > QUANTILE) <= 0.001, (label, nees)
    assert repaired >= 1


def test_an_undetectable_spoofer_is_not_excluded():
    """The default 50 km moves a line of sight by under 2 deg: the residual test passes at
    every epoch and the exclusion changes nothing.  (The two-step method flags the epochs
    where antenna 1's few cones fit a second boresight, spoofer or not.)"""
    for label, (track, _) in _solved({"aircraft": [SPOOFED]}, True).items():
        flagged = track.reason[~track.valid]
        if label == "deterministic":
            assert all("a second direction" in reason for reason in flagged), flagged
        else:
            assert track.valid.all(), label
        assert np.all(track.diagnostics["n_excluded"][track.valid] == 0), label


# --- the exclusion on synthetic epochs ----------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(
    scores=st.lists(st.floats(-5.0, 5.0), min_size=8, max_size=8),
    seed=st.integers(0, 2**32 - 1),
)
def test_the_exclusion_statistic_is_the_drop_of_the_linear_chi_square(scores, seed):
    """For a linear model ``T_g`` is exactly the chi-square of the least-squares
    residuals minus that of the fit without group ``g``."""
    rng = np.random.default_rng(seed)
    jacobian = rng.normal(size=(8, 3))
    group = np.array([0, 0, 1, 2, 3, 4, 5, 5])
    s = np.asarray(scores)
    statistics = exclusion_statistics(Residuals(s, jacobian), group, 6)
    full = s @ parity_projection(jacobian) @ s
    for g in range(6):
        keep = group != g
        reduced = s[keep] @ parity_projection(jacobian[keep]) @ s[keep]
        assert statistics[g] == pytest.approx(full - reduced, rel=1e-9, abs=1e-9)


def _faulty_epoch(seed: int, bad: list[int], error_db: float, transmitter=None):
    rng = np.random.default_rng(seed)
    geometry = _geometry(rng, TRUTH, per_antenna=(12, 12))
    measured = geometry[3] + rng.standard_normal(geometry[3].size)
    measured[bad] += error_db
    ids = np.arange(measured.size) + 100 if transmitter is None else transmitter
    return _epoch(geometry, np.maximum(measured, 6.0), transmitter=ids)


@settings(max_examples=4, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    bad=st.integers(0, 23),
    error_db=st.floats(12.0, 30.0),
)
@pytest.mark.parametrize("name", SNAPSHOT)
def test_one_grossly_wrong_observation_is_excluded(name, seed, bad, error_db):
    """One SNR 12-30 dB off: the epoch is valid, with that transmitter excluded, and its
    estimate is the method's estimate of the epoch without it; without the exclusion it
    is flagged ``model mismatch``."""
    problem = _faulty_epoch(seed, [bad], error_db)
    solver = SOLVERS[name]
    track = solver.solve_sequence(_snapshots([problem]), prior=TRUTH)
    assert track.valid[0], track.reason[0]
    assert track.diagnostics["n_excluded"][0] == 1
    assert track.diagnostics["excluded_transmitter"][0] == 100 + bad
    alone = solver.solve_sequence(_snapshots([problem.take(np.arange(problem.m) != bad)]), TRUTH)
    assert np.array_equal(track.quaternion, alone.quaternion)
    assert np.array_equal(track.covariance, alone.covariance)
    off = replace(solver, fault_exclusion=False).solve_sequence(_snapshots([problem]), TRUTH)
    assert off.reason[0].startswith("model mismatch")


@pytest.mark.parametrize("name", SNAPSHOT)
def test_two_wrong_observations_of_two_aircraft_are_flagged(name):
    """Two transmitters 15 dB off: excluding either one leaves the other, so the epoch is
    flagged, naming the failed exclusion."""
    problem = _faulty_epoch(5, [2, 17], 15.0)
    track = SOLVERS[name].solve_sequence(_snapshots([problem]), prior=TRUTH)
    assert not track.valid[0]
    assert track.reason[0].startswith("model mismatch")
    assert "fails too" in track.reason[0]
    assert track.error[0].__name__ == "ModelMismatchError"


@pytest.mark.parametrize("name", SNAPSHOT)
def test_two_wrong_observations_of_one_aircraft_are_excluded_together(name):
    """Both rows of one transmitter 15 dB off (two messages of one aircraft): the
    transmitter is excluded with both its rows."""
    ids = np.arange(24) + 100
    ids[17] = ids[2]
    problem = _faulty_epoch(5, [2, 17], 15.0, transmitter=ids)
    track = SOLVERS[name].solve_sequence(_snapshots([problem]), prior=TRUTH)
    assert track.valid[0], track.reason[0]
    assert track.diagnostics["excluded_transmitter"][0] == 102


@pytest.mark.parametrize("name", ONE_STEP)
def test_too_few_observations_to_isolate_are_flagged(name):
    """Four observations, one 20 dB off: without any one of them three remain, no
    redundancy to test, so the epoch is flagged rather than guessed."""
    problem = _faulty_epoch(7, [1], 20.0).take(np.array([0, 1, 12, 13]))
    track = SOLVERS[name].solve_sequence(_snapshots([problem]), prior=TRUTH)
    assert not track.valid[0]
    assert "no aircraft can be isolated" in track.reason[0]


@pytest.mark.parametrize("name", SNAPSHOT)
def test_an_epoch_that_passes_its_test_is_not_touched(name):
    """Fault-free: the exclusion on or off gives the same track, bit for bit."""
    problems = [_faulty_epoch(seed, [], 0.0) for seed in (1, 2)]
    solver = SOLVERS[name]
    on = solver.solve_sequence(_snapshots(problems), prior=TRUTH)
    off = replace(solver, fault_exclusion=False).solve_sequence(_snapshots(problems), TRUTH)
    assert on.valid.all()
    for field in ("quaternion", "covariance", "loss"):
        assert np.array_equal(getattr(on, field), getattr(off, field)), field
    assert np.all(on.diagnostics["n_excluded"] == 0)


def test_a_chi_square_that_is_not_finite_is_a_mismatch():
    """A residual the model cannot predict at the estimate makes the chi-square NaN: that
    is a mismatch, not an epoch without a test."""
    assert residual_test(float("nan"), 20).startswith("model mismatch")
    assert residual_test(float("nan"), 0) is None


def test_a_message_from_behind_the_antenna_is_excluded_by_the_two_step_method():
    """One line of sight turned away from its antenna (a position far off): the two-step
    method's eq. 19 loss is NaN at its attitude; the epoch is repaired by excluding that
    transmitter, or flagged without the exclusion."""
    problem = _faulty_epoch(3, [], 0.0)
    los = problem.los_orbit.copy()
    los[4] = -los[4]
    problem = replace(problem, los_orbit=los)
    solver = SOLVERS["deterministic"]
    off = replace(solver, fault_exclusion=False).solve_sequence(_snapshots([problem]), TRUTH)
    assert off.reason[0].startswith("model mismatch"), off.reason[0]
    track = solver.solve_sequence(_snapshots([problem]), prior=TRUTH)
    assert track.valid[0], track.reason[0]
    assert track.diagnostics["excluded_transmitter"][0] == 104


def test_the_faults_example_of_the_configuration_guide_loads(tmp_path):
    """The TOML block of ``docs/configuration.md``'s Faults section is an adsb-snr config."""
    text = (Path(__file__).resolve().parent.parent / "docs" / "configuration.md").read_text()
    section = text.split("\n## Faults\n")[1].split("\n## ")[0]
    (block,) = re.findall(r"^```toml\n(.*?)^```$", section, flags=re.MULTILINE | re.DOTALL)
    config = tmp_path / "faults.toml"
    config.write_text(block)
    parameters = resolve_parameters(EXPERIMENT, config=config)
    assert parameters.traffic.spoofer.offset_km == 50.0
    assert parameters.receiver.outliers.offset_db == 20.0
