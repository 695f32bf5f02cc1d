"""The attopt command line and the experiment registry."""

from __future__ import annotations

import dataclasses

import pytest
from typer.testing import CliRunner

from attopt import ESTIMATORS, estimators
from attopt.experiments import registry
from attopt.experiments.cli import app
from attopt.experiments.registry import UnknownExperimentError, get_experiment, reference_of
from tests.sweep_toys import TOY

runner = CliRunner()


def test_run_prints_where_results_went_and_the_summary(tmp_path):
    out = tmp_path / "out"
    result = runner.invoke(
        app, ["run", "noop", "--quick", "--workers", "1", "--out", str(out), "--no-progress"]
    )
    assert result.exit_code == 0, result.output
    assert f"Results in {out}/" in result.output
    assert "total_rms_deg" in result.output and "noop" in result.output
    assert "100 trials: 100 computed now, 0 already done, 0 failed, 0 missing" in result.output
    assert (out / "summary.csv").exists() and (out / "report.md").exists()

    again = runner.invoke(
        app, ["run", "noop", "--quick", "--workers", "1", "--out", str(out), "--no-progress"]
    )
    assert "0 computed now, 100 already done" in again.output


def test_run_accepts_an_import_path_and_reports_failures(tmp_path):
    config = tmp_path / "fail.toml"
    config.write_text("fail_every = 2\n")
    options = ["--workers", "1", "--config", str(config), "--out", str(tmp_path / "out")]
    result = runner.invoke(
        app, ["run", "tests.sweep_toys:TOY", "--quick", *options, "--no-progress"]
    )
    assert result.exit_code == 0, result.output
    assert "1 failed" in result.output
    assert "failed: 1 x ValueError: unlucky trial 1" in result.output


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["run", "nope"], "unknown experiment 'nope'; known experiments: "),
        (["run", "no_such_module:EXPERIMENT"], "No module named 'no_such_module'"),
        (["run", "noop", "--engine", "local", "--address", "tcp://x:8786"], "--address"),
        (
            ["run", "noop", "--engine", "dask", "--address", "tcp://x:8786", "--workers", "2"],
            "--workers sets the size of a local cluster",
        ),
    ],
)
def test_usage_errors_exit_with_a_message(tmp_path, arguments, message):
    result = runner.invoke(app, [*arguments, "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert message in result.output


def test_bad_config_key_is_named(tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text("sleep = 1.0\n")
    result = runner.invoke(app, ["run", "noop", "--config", str(config), "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert "unknown key 'sleep'" in result.output and "sleep_s" in result.output


def test_list_shows_names_and_summaries_even_with_a_broken_entry(monkeypatch):
    monkeypatch.setitem(registry.EXPERIMENTS, "broken", "no_such_module:EXPERIMENT")
    result = runner.invoke(app, ["list"])
    assert result.exit_code == 0
    assert "noop" in result.output and "No-op trial" in result.output
    assert "broken" in result.output and "cannot be loaded" in result.output
    with pytest.raises(ModuleNotFoundError):
        get_experiment("broken")


def test_registry_lookup_and_reference():
    assert get_experiment("tests.sweep_toys:TOY") is TOY
    assert reference_of(TOY) == "tests.sweep_toys:TOY"
    with pytest.raises(UnknownExperimentError, match=r"known experiments:.*noop"):
        get_experiment("toy")
    with pytest.raises(TypeError, match="not an Experiment"):
        get_experiment("tests.sweep_toys:toy_grid")
    with pytest.raises(ValueError, match="module-level"):
        reference_of(dataclasses.replace(TOY, name="copy"))


def test_estimators_lists_the_registry_by_kind():
    listed = CliRunner().invoke(app, ["estimators"])
    assert listed.exit_code == 0
    assert [line.split()[0] for line in listed.output.splitlines()] == list(ESTIMATORS)
    passes = CliRunner().invoke(app, ["estimators", "--kind", "pass"])
    assert [line.split()[0] for line in passes.output.splitlines()] == estimators("pass")
    assert "fg_batch_offsets  pass  SnrMeasurement" in passes.output


def test_check_groups_a_sweep_as_its_report_does(tmp_path):
    from attopt.experiments.sweep import run_sweep

    out = tmp_path / "toy"
    run_sweep(TOY, trials=2, out=out, workers=1, progress=False)
    result = runner.invoke(app, ["check", str(out)])
    assert result.exit_code == 0, result.output
    header = result.output.splitlines()[0].split()
    # the setting columns that vary (the manifest's order), then the group_by columns
    assert sorted(header[:2]) == ["label", "scale"] and header[2] == "method"
    assert "no NEES in the rows" in result.output


def test_check_names_the_worst_group_and_fails_above_max_share(tmp_path):
    import pandas as pd

    rows = pd.DataFrame(
        {
            "method": ["good"] * 4 + ["overconfident"] * 4,
            "valid": True,
            **{f"err_{a}_deg": 0.1 for a in "xyz"},
            "nees": [1.0, 2.0, 3.0, 4.0, 2.0, 30.0, 50.0, 3.0],
        }
    )
    rows.to_parquet(tmp_path / "rows.parquet")
    result = runner.invoke(app, ["check", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "quantile 0.5 (method=overconfident)" in result.output
    strict = runner.invoke(app, ["check", str(tmp_path), "--max-share", "0.001"])
    assert strict.exit_code == 1
    lenient = runner.invoke(app, ["check", str(tmp_path), "--max-share", "0.5"])
    assert lenient.exit_code == 0


def test_check_of_a_directory_without_results_exits_2(tmp_path):
    result = runner.invoke(app, ["check", str(tmp_path)])
    assert result.exit_code == 2
    assert "not a results directory" in result.output
