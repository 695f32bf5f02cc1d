"""``geo-snr-stations`` exports the pass its gyro-aided filters solve (``docs/pass-format.md``).

The exported pass, saved and loaded, gives the trial's filter tracks bit for bit
(Pimienta-Penalver and Crassidis's USQUE and the MEKF with the trial's options),
``attopt estimate`` reproduces the trial's rows where the registry's default options
do not act, and ``attopt export geo-snr-stations --quick`` writes it.
"""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from attopt import load_pass, save_pass
from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.geo_snr_stations import experiment as geo
from attopt.experiments.geo_snr_stations.pointing import track_pointing
from attopt.experiments.metrics import pointing_error
from attopt.experiments.recorded.estimate import estimate, method_rows
from attopt.experiments.recorded.export import exporter
from attopt.experiments.sweep.seeding import trial_seed
from attopt.formulations.geo_link import BORESIGHT_BODY
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.pipeline import run_estimators

runner = CliRunner()
FILTERS = ("usque", "mekf")


@functools.cache
def _geo(manoeuvre: bool, duration_s: float = 1800.0):
    """A short setting of the quick parameters with the two filters, and a trial seed."""
    setting = {
        **geo.EXPERIMENT.parameters,
        **geo.EXPERIMENT.quick_parameters,
        "duration_s": duration_s,
        "manoeuvre": manoeuvre,
        "methods": ["cone"],
        "filters": list(FILTERS),
    }
    return setting, trial_seed(0, 0, 1)


def _filter_pass(setting, seed):
    """The pass trial(setting, seed) gives its filters, built as the trial builds it."""
    parameters, scenario, snr = geo.simulate(setting, seed)
    filter_snr = geo.filter_snrs(snr, geo.filter_station_indices(parameters, scenario))
    start = geo.cone_start(geo.cone_pointing(parameters, scenario, snr))
    return scenario, geo.filter_pass(parameters, seed, scenario, filter_snr, start)


def _same_track(a, b) -> bool:
    return all(
        np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
        for f in ("quaternion", "covariance", "valid")
    )


def test_exported_geo_pass_estimates_bit_identically_after_save_and_load(tmp_path):
    # With the manoeuvre (its innovations act on the filters) and the trial's options,
    # configured(name), on both sides.
    setting, seed = _geo(manoeuvre=True, duration_s=3600.0)
    recorded = exporter("geo-snr-stations")(setting, seed)
    loaded = load_pass(save_pass(recorded, tmp_path / "geo"))
    scenario, in_memory = _filter_pass(setting, seed)
    for candidate in (recorded, loaded):
        assert candidate.metadata.attitude_frame == "eci" and candidate.frames is None
        assert candidate.gyro_pass.prior.attitude.as_quat().tolist() == (
            in_memory.prior.attitude.as_quat().tolist()
        )
        assert np.array_equal(candidate.gyro_pass.gyro.rates, in_memory.gyro.rates)
        ours, theirs = candidate.gyro_pass.measurements(), in_memory.measurements()
        assert len(ours) == len(theirs) == scenario.t.size
        for a, b in zip(ours, theirs, strict=True):
            assert (a is None) == (b is None)
            if a is None:
                continue
            assert isinstance(a, SnrMeasurement) and isinstance(b, SnrMeasurement)
            for name in ("snr_db", "los_orbit", "p0_dbw", "sigma_db", "boresights_body"):
                assert np.array_equal(getattr(a.epoch, name), getattr(b.epoch, name)), name
            assert a.epoch.pattern == b.epoch.pattern
            assert (a.epoch.noise_dbw, a.epoch.threshold_db) == (
                b.epoch.noise_dbw,
                b.epoch.threshold_db,
            )
        for name in FILTERS:
            chosen = {name: geo.configured(name)}
            expected = run_estimators(in_memory, chosen)[name].track
            got = run_estimators(candidate.gyro_pass, chosen)[name].track
            assert _same_track(got, expected), name


def test_the_exported_pass_with_the_trials_options_gives_the_trials_filter_rows(tmp_path):
    setting, seed = _geo(manoeuvre=True, duration_s=3600.0)
    rows = geo.trial(setting, seed)
    recorded = load_pass(save_pass(exporter("geo-snr-stations")(setting, seed), tmp_path / "p"))
    scenario, _ = _filter_pass(setting, seed)
    n_stations = np.bincount(
        np.searchsorted(recorded.t, recorded.tables["snr"]["t_s"]), minlength=recorded.t.size
    )
    for name in FILTERS:
        track = run_estimators(recorded.gyro_pass, {name: geo.configured(name)})[name].track
        ours = track_pointing(scenario, track, n_stations).frame(name, scenario)
        theirs = rows[rows["method"] == name].reset_index(drop=True)
        pd.testing.assert_frame_equal(ours, theirs, check_exact=True)


def test_estimating_the_exported_geo_pass_gives_the_experiments_rows():
    # Without the manoeuvre the registry's default gate and validity limit, which
    # `attopt estimate` uses, do not act: its rows are the trial's (export docstring).
    setting, seed = _geo(manoeuvre=False)
    rows = geo.trial(setting, seed)
    recorded = exporter("geo-snr-stations")(setting, seed)
    same = [
        "sigma_x_deg",
        "sigma_y_deg",
        "sigma_z_deg",
        "valid",
        *(f"q_{kind}_{c}" for kind in ("est", "true") for c in "xyzw"),
    ]
    for name, run in estimate(recorded, list(FILTERS)).items():
        ours = method_rows(name, run, recorded)
        theirs = rows[rows["method"] == name].reset_index(drop=True)
        assert ours["valid"].all()
        assert np.array_equal(ours["t_s"], theirs["t_s"])
        for column in same:
            assert np.array_equal(ours[column], theirs[column], equal_nan=True), (name, column)
        # The trial's yaw error is the attitude error's z; its err_{x,y} the pointing error.
        assert np.array_equal(ours["err_z_deg"], theirs["yaw_err_deg"], equal_nan=True), name
        estimated = run.track.attitude().inv().apply(BORESIGHT_BODY)
        pointing = np.degrees(pointing_error(recorded.truth, estimated))
        for i, axis in enumerate("xy"):
            assert np.array_equal(pointing[:, i], theirs[f"err_{axis}_deg"]), (name, axis)


def test_cli_export_writes_the_quick_trials_pass(tmp_path):
    out = tmp_path / "pass"
    result = runner.invoke(app, ["export", "geo-snr-stations", str(out), "--quick"])
    assert result.exit_code == 0, result.output
    document = resolve_parameters(geo.EXPERIMENT, quick=True).model_dump(mode="json")
    setting = geo.EXPERIMENT.grid(document)[0]
    expected = exporter("geo-snr-stations")(setting, trial_seed(0, 0, 0))
    loaded = load_pass(out)
    assert loaded.metadata == expected.metadata
    assert sorted(loaded.tables) == sorted(expected.tables)
    for name, table in expected.tables.items():
        pd.testing.assert_frame_equal(loaded.tables[name], table, check_exact=True)
    stations = set(loaded.tables["snr"]["transmitter"])
    names = [geo.GeoSnrStationsParameters().stations[i].name for i in stations]
    assert sorted(names) == sorted(setting["filter_stations"])
    estimated = runner.invoke(
        app, ["estimate", str(out), "--methods", "usque", "--out", str(tmp_path / "est")]
    )
    assert estimated.exit_code == 0, estimated.output
    rows = pd.read_parquet(tmp_path / "est" / "rows.parquet")
    trial_rows = geo.trial(
        {**setting, "methods": ["cone"], "filters": ["usque"]}, trial_seed(0, 0, 0)
    )
    usque = trial_rows[trial_rows["method"] == "usque"].reset_index(drop=True)
    for column in ("valid", "q_est_x", "q_est_w", "sigma_x_deg"):
        assert np.array_equal(rows[column], usque[column], equal_nan=True), column


def test_the_truth_table_loads_as_the_trials_truth(tmp_path):
    setting, seed = _geo(manoeuvre=True, duration_s=3600.0)
    loaded = load_pass(save_pass(exporter("geo-snr-stations")(setting, seed), tmp_path / "p"))
    _, scenario, _ = geo.simulate(setting, seed)
    assert np.array_equal(loaded.t, scenario.t)
    assert np.array_equal(loaded.truth.as_quat(), scenario.truth.as_quat())
