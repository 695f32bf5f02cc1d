"""The mismatch cases and the switch that turns the integrity tests off
(``attopt.experiments.benchmarks.integrity``, ``integrity_tests_off``)."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.benchmarks.integrity import (
    CASES,
    case,
    format_table,
    group_statistics,
    options_without_tests,
    side_by_side,
)
from attopt.experiments.config import resolve_parameters
from attopt.experiments.estimators import configured
from attopt.experiments.registry import get_experiment
from attopt.solvers.registry import ESTIMATORS, INTEGRITY_TESTS, integrity_tests_off


def _leaves(table: dict) -> list:
    return [
        v
        for value in table.values()
        for v in (_leaves(value) if isinstance(value, dict) else [value])
    ]


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_integrity_tests_off_turns_every_test_off_and_nothing_else(name):
    found = ESTIMATORS[name]
    table = integrity_tests_off(found)
    off = configured(name, {name: table})
    assert integrity_tests_off(off) == table  # the same fields, now holding the off values
    assert all(v in INTEGRITY_TESTS.values() for v in _leaves(table))
    # the options differ from the defaults exactly where the table says
    assert (off == found) == (not table)


def test_the_filters_and_the_snapshot_least_squares_have_their_tests_switchable():
    for name in ("mekf", "usque", "rts", "ekf_yang2014"):
        assert "consistency_window" in str(integrity_tests_off(ESTIMATORS[name]))
    for name in ("ekf_yang2014", "rts_yang2014"):  # and the check against the other runs
        table = str(integrity_tests_off(ESTIMATORS[name]))
        assert "'start_hypotheses': 'none'" in table and "'robust_check': False" in table
    for name in ("deterministic", "nlse", "nlp", "nlp_truncated"):
        assert integrity_tests_off(ESTIMATORS[name]) == {"mismatch_false_alarm": 0.0}
    for name in ("fg_batch", "fg_batch_offsets"):  # the window, variance factor, gyro test
        table = integrity_tests_off(ESTIMATORS[name])
        assert table["max_variance_factor"] == 1.0 and table["gyro_exclusions"] == 0
        assert table["filter"] == {"consistency_window": 0}


@pytest.mark.parametrize("mismatch", CASES, ids=lambda c: c.name)
def test_every_case_is_a_valid_config_of_its_experiment_with_the_tests_on_and_off(mismatch):
    experiment = get_experiment(mismatch.experiment)
    on = resolve_parameters(experiment, quick=True, overrides=mismatch.parameters)
    off = resolve_parameters(
        experiment, quick=True, overrides={**mismatch.parameters, **options_without_tests()}
    )
    assert on.model_dump(exclude={"estimator_options"}) == off.model_dump(
        exclude={"estimator_options"}
    )
    document = on.model_dump(mode="json")
    for key, value in mismatch.parameters.items():
        assert key in document and value is not None
    assert mismatch.what


def test_an_unknown_case_names_the_cases():
    with pytest.raises(KeyError, match="power-offsets"):
        case("no-such-case")


def test_group_statistics_and_the_table_put_off_beside_on():
    rows = pd.DataFrame(
        {
            "method": ["a", "a", "a", "a"],
            "valid": [True, True, True, False],
            "err_x_deg": [3.0, 4.0, 0.0, np.nan],
            "err_y_deg": 0.0,
            "err_z_deg": 0.0,
            "nees": [1.0, 30.0, 2.0, np.nan],
            "reason": ["", "", "", "lost track: x"],
        }
    )
    stats = group_statistics(rows, ["method"])
    assert stats.loc["a", "valid"] == 0.75
    assert stats.loc["a", "RMS (deg)"] == pytest.approx(np.sqrt(25.0 / 3.0))
    assert stats.loc["a", "share"] == pytest.approx(1.0 / 3.0)
    table = side_by_side(stats, group_statistics(rows.iloc[:3], ["method"]))
    text = format_table(table.reset_index().assign(case="toy"))
    assert "| toy | a | 0.750 -> 1.000 | 2.89 -> 2.89 | 0.333 -> 0.333 |" in text


def test_a_printed_case_config_loads_back(capsys, monkeypatch):
    from attopt.experiments.benchmarks import integrity

    monkeypatch.setattr("sys.argv", ["integrity", "--print-config", "outlier-burst"])
    integrity.main()
    printed = capsys.readouterr().out
    assert printed.startswith("# attopt run adsb-snr")
    assert tomllib.loads(printed) == case("outlier-burst").parameters


def test_the_integrity_page_lists_every_case():
    from pathlib import Path

    page = (Path(__file__).parents[1] / "docs" / "integrity.md").read_text()
    for mismatch in CASES:
        assert f"| `{mismatch.name}` | `{mismatch.experiment}` |" in page, mismatch.name
