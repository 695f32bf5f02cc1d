"""Parameters from TOML: validated by the experiment's schema, every error reported."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.config import ConfigError, describe, resolve_parameters, starter_toml
from attopt.experiments.config.loading import load_config
from attopt.experiments.registry import EXPERIMENTS, get_experiment
from attopt.experiments.sweep import run_sweep
from tests.sweep_toys import TOY


def write(tmp_path, text, name="sweep.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_config_applies_after_quick_parameters_and_merges_tables(tmp_path):
    config = write(tmp_path, "rows_per_trial = 5\nmethods = ['x']\n[nested]\nname = 'y'\n")
    parameters = resolve_parameters(TOY, quick=True, config=config)
    assert parameters.rows_per_trial == 5
    assert parameters.methods == ["x"]
    assert parameters.scales == [1.0]  # from quick_parameters
    assert parameters.fail_every == TOY.parameters["fail_every"]
    assert parameters.nested.name == "y" and parameters.nested.altitude_km == 600.0


def test_integers_are_accepted_where_floats_are_expected(tmp_path):
    scales = resolve_parameters(TOY, config=write(tmp_path, "scales = [1, 2.5]\n")).scales
    assert scales == [1.0, 2.5] and all(isinstance(s, float) for s in scales)


def test_every_error_is_reported_at_once_with_its_key_path(tmp_path):
    config = write(
        tmp_path,
        "rows_per_trail = 5\nrows_per_trial = 0\nas_frame = 'yes'\n"
        "scales = [1.0, 'x']\n[nested]\naltitude_km = -1\ncolour = 'red'\n",
    )
    with pytest.raises(ConfigError) as raised:
        resolve_parameters(TOY, config=config)
    problems = raised.value.problems
    assert len(problems) == 6, problems
    text = "\n".join(problems)
    assert "unknown key 'rows_per_trail'; valid keys here: " in text and "rows_per_trial" in text
    assert "rows_per_trial = 0: Input should be greater than or equal to 1" in text
    assert "as_frame = 'yes'" in text
    assert "scales[1] = 'x'" in text
    assert "nested.altitude_km = -1: Input should be greater than 0" in text
    assert "unknown key 'nested.colour'; valid keys here: altitude_km, name" in text
    assert str(config) in str(raised.value)


def test_invalid_toml_and_missing_files_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(write(tmp_path, "[nested\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.toml")


def test_sweep_refuses_a_bad_config_before_running(tmp_path):
    config = write(tmp_path, "bogus = 1\n")
    with pytest.raises(ConfigError, match="'bogus'"):
        run_sweep(TOY, out=tmp_path / "out", config=config, workers=1, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", sorted(EXPERIMENTS))
def test_starter_toml_round_trips_to_the_defaults(tmp_path, name):
    experiment = get_experiment(name)
    defaults = resolve_parameters(experiment)
    config = write(tmp_path, starter_toml(defaults, "header"))
    assert resolve_parameters(experiment, config=config) == defaults
    paths = [leaf.path for leaf in describe(experiment.schema, defaults)]
    assert len(paths) == len(set(paths)) and all(
        leaf.description for leaf in describe(experiment.schema)
    )


def test_effective_config_is_written_and_reruns_the_sweep(tmp_path):
    config = write(tmp_path, "rows_per_trial = 2\n[nested]\nname = 'z'\n")
    first = run_sweep(TOY, out=tmp_path / "a", config=config, trials=2, workers=1, progress=False)
    effective = first.out_dir / "config.toml"
    again = run_sweep(
        TOY, out=tmp_path / "b", config=effective, trials=2, workers=1, progress=False
    )
    assert again.parameters == first.parameters
    assert again.parameters["nested"]["name"] == "z"


def test_resume_with_another_config_names_the_nested_key(tmp_path):
    out = tmp_path / "out"
    run_sweep(TOY, out=out, trials=1, workers=1, progress=False)
    with pytest.raises(ValueError, match=r"parameter 'nested.altitude_km' 600.0 -> 700.0"):
        run_sweep(
            TOY,
            out=out,
            trials=1,
            workers=1,
            progress=False,
            overrides={"nested": {"altitude_km": 700.0}},
        )


@pytest.mark.parametrize(
    "text",
    [
        'gyro = "navgrade"\n',
        'methods = ["quest", "davenport"]\n',
        "duration_s = -5\n",
        "duration_s = 'long'\n",
        "bogus = 1\n",
        "[gyro]\nrate_hz = 0\n",
        "duration_s = \n",
    ],
)
def test_cli_bad_config_values_exit_2_with_one_line_each(tmp_path, text):
    config = write(tmp_path, text)
    result = CliRunner().invoke(
        app,
        ["run", "wahba-mag-sun", "--quick", "--config", str(config), "--out", str(tmp_path / "o")],
    )
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert lines and all(line.startswith(f"error: {config}") for line in lines), lines
    assert "Traceback" not in result.output
    assert not (tmp_path / "o").exists()


def test_cli_missing_config_file_exits_2(tmp_path):
    result = CliRunner().invoke(app, ["run", "noop", "--config", str(tmp_path / "none.toml")])
    assert result.exit_code == 2 and "cannot read config" in result.stderr


def test_cli_show_lists_every_parameter_and_prints_a_starter_config():
    listing = CliRunner().invoke(app, ["show", "wahba-mag-sun"])
    assert listing.exit_code == 0
    assert "duration_s" in listing.stdout and "Length of the pass" in listing.stdout
    starter = CliRunner().invoke(app, ["show", "wahba-mag-sun", "--toml"])
    assert starter.exit_code == 0 and starter.stdout.startswith("# attopt run wahba-mag-sun")


def test_cli_show_lists_the_fields_of_tables_inside_a_list():
    """adsb-snr's ``gyros`` holds presets or ``[[gyros]]`` tables: both are listed, the
    table's fields with their units."""
    listing = CliRunner().invoke(app, ["show", "adsb-snr"]).stdout
    assert "gyros " in listing
    rate = next(line for line in listing.splitlines() if line.startswith("gyros[](table).rate_hz"))
    assert "Hz" in rate.split()


def test_cli_show_marks_a_field_without_a_default_as_required():
    """A burst's start has no default; a table gain's angles default to an empty list."""
    listing = CliRunner().invoke(app, ["show", "adsb-snr"]).stdout
    lines = {line.split()[0]: line.split()[1] for line in listing.splitlines() if line.strip()}
    assert lines["receiver.outliers(table).start_s"] == "(required)"
    assert lines["antennas[0].gain(type=table).angle_deg"] == "[]"
    assert "Undefined" not in listing


def test_default_out_includes_the_config_name(tmp_path):
    from pathlib import Path

    from attopt.experiments.cli import default_out

    assert default_out("adsb-snr", Path("configs/three.toml"), True) == Path(
        "results/adsb-snr-three-quick"
    )
    assert default_out("adsb-snr", None, False) == Path("results/adsb-snr")
