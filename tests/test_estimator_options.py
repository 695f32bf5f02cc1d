"""``[estimator_options.NAME]``: every experiment's estimators take their options from the
configuration, a change reaches that estimator's rows alone, and a bad table is one line
and exit status 2."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from attopt.experiments.adsb_snr.experiment import EXPERIMENT as ADSB
from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.config.loading import deep_merge
from attopt.experiments.doa_ground.experiment import EXPERIMENT as DOA
from attopt.experiments.geo_snr_stations.experiment import EXPERIMENT as GEO
from attopt.experiments.wahba_mag_sun.experiment import EXPERIMENT as WAHBA
from attopt.solvers.registry import estimator, with_options

SEED = np.random.SeedSequence(0, spawn_key=(0, 0))
NOTHING_DETERMINED = {"filter": {"max_attitude_sigma": 1e-9}}
"""Filter options under which no epoch's attitude counts as determined: every row flagged."""
CASES = {
    "wahba-mag-sun": (
        WAHBA,
        {"duration_s": 60.0, "methods": ["quest"], "filters": ["mekf", "usque"]},
        {"mekf": NOTHING_DETERMINED},
        "mekf",
        "usque",
    ),
    "adsb-snr": (
        ADSB,
        {
            "start_utc": "2025-06-02T02:01:00",
            "duration_s": 12.0,
            "step_s": 2.0,
            "traffic": {"n_aircraft": 600},
            "methods": ["nlse", "nlp"],
            "filters": [],
        },
        {"nlp": {"mismatch_false_alarm": 0.999999}},
        "nlp",
        "nlse",
    ),
    "geo-snr-stations": (
        GEO,
        {
            "duration_s": 600.0,
            "step_s": 60.0,
            "manoeuvre": [False],
            "methods": ["lsq"],
            "filters": ["usque", "mekf"],
        },
        {"usque": NOTHING_DETERMINED},
        "usque",
        "mekf",
    ),
    "doa-ground": (
        DOA,
        {
            "duration_s": 60.0,
            "settle_s": 30.0,
            "row_step_s": 5.0,
            "table1_snr_db": [0.0],
            "table2_snapshots": [],
            "process_noise": [1e-12],
            "filter_trials": 0,
            # 60 s from the paper's start is too short for the check to confirm an epoch:
            # without it the EKF's rows are valid, and the option tested flags them
            "estimator_options": {
                "ekf_yang2014": {"start_hypotheses": "none", "robust_check": False}
            },
        },
        {"ekf_yang2014": NOTHING_DETERMINED},
        "ekf_yang2014_q1e-12",  # (and its RTS pass, which keeps the EKF's flags)
        "wahba",
    ),
}
runner = CliRunner()


def _rows(experiment, overrides: dict) -> pd.DataFrame:
    parameters = resolve_parameters(experiment, overrides=overrides)
    (setting, *_) = experiment.grid(parameters.model_dump(mode="json"))
    return experiment.trial(setting, SEED)


def _method(rows: pd.DataFrame, label: str) -> pd.DataFrame:
    return (
        rows[rows["method"] == label]
        .drop(columns="runtime_s", errors="ignore")
        .reset_index(drop=True)
    )


@pytest.mark.parametrize("name", sorted(CASES))
def test_an_estimators_options_change_its_rows_alone(name):
    """The option flags every row of the estimator it names (a validity limit no
    attitude meets, or a residual test that rejects almost every epoch); the other
    estimator's rows are bit for bit those of the defaults."""
    experiment, base, options, changed, other = CASES[name]
    default = _rows(experiment, base)
    configured = _rows(experiment, deep_merge(base, {"estimator_options": options}))
    assert _method(default, changed)["valid"].mean() > 0.5
    assert not _method(configured, changed)["valid"].any()
    pd.testing.assert_frame_equal(_method(configured, other), _method(default, other))


def test_options_reach_nested_options_objects_and_keep_the_rest():
    mekf = with_options(estimator("mekf"), {"filter": {"gate_probability": 0.99}})
    assert mekf.filter.gate_probability == 0.99
    assert mekf.filter.max_gyro_gap_s == estimator("mekf").filter.max_gyro_gap_s
    nlp = with_options(estimator("nlp"), {"options": {"max_iter": 7}, "warm_start": {}})
    assert nlp.options.max_iter == 7 and nlp.warm_start == estimator("nlp").warm_start


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("[estimator_options.nope]\nx = 1\n", "unknown estimator 'nope'"),
        ("[estimator_options.mekf]\ngate = 0.9\n", "has no option gate"),
        ("[estimator_options.mekf.filter]\ngate = 0.9\n", "FilterOptions has no option gate"),
        ("[estimator_options.quest.parallel_tolerance]\nx = 1\n", "takes a value, not a table"),
    ],
)
def test_a_bad_options_table_is_one_line_and_exit_2(tmp_path, table, message):
    config = tmp_path / "bad.toml"
    config.write_text(table)
    result = runner.invoke(app, ["run", "wahba-mag-sun", "--config", str(config)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "estimator_options" in lines[0] and message in lines[0]
