"""Parameter overrides from TOML: unknown keys and wrong types are named."""

from __future__ import annotations

import pytest

from attopt.experiments.sweep import ConfigError, resolve_parameters, run_sweep
from tests.sweep_toys import TOY


def write(tmp_path, text):
    path = tmp_path / "sweep.toml"
    path.write_text(text)
    return path


def test_overrides_apply_after_quick_parameters(tmp_path):
    config = write(tmp_path, "[parameters]\nrows_per_trial = 5\nmethods = ['x']\n")
    parameters = resolve_parameters(TOY, quick=True, config=config)
    assert parameters["rows_per_trial"] == 5
    assert parameters["methods"] == ["x"]
    assert parameters["scales"] == [1.0]  # from quick_parameters
    assert parameters["fail_every"] == TOY.parameters["fail_every"]


def test_integers_are_accepted_where_floats_are_expected(tmp_path):
    config = write(tmp_path, "[parameters]\nscales = [1, 2.5]\n")
    scales = resolve_parameters(TOY, config=config)["scales"]
    assert scales == [1.0, 2.5] and all(isinstance(s, float) for s in scales)


def test_unknown_parameter_is_named_with_the_valid_ones(tmp_path):
    config = write(tmp_path, "[parameters]\nrows_per_trail = 5\n")
    with pytest.raises(ConfigError, match="unknown parameter 'rows_per_trail'") as error:
        resolve_parameters(TOY, config=config)
    assert "rows_per_trial" in str(error.value) and str(config) in str(error.value)


@pytest.mark.parametrize(
    ("line", "key", "expected"),
    [
        ("rows_per_trial = 2.5", "'rows_per_trial'", "an integer"),
        ("rows_per_trial = true", "'rows_per_trial'", "an integer"),
        ("as_frame = 1", "'as_frame'", "a boolean"),
        ("methods = 'a'", "'methods'", "an array"),
        ("methods = ['a', 2]", r"'methods\[1\]'", "a string"),
        ("scales = [1.0, 'x']", r"'scales\[1\]'", "a number"),
    ],
)
def test_wrong_types_are_named(tmp_path, line, key, expected):
    config = write(tmp_path, f"[parameters]\n{line}\n")
    with pytest.raises(ConfigError, match=f"parameter {key} .* must be {expected}"):
        resolve_parameters(TOY, config=config)


def test_unknown_top_level_keys_and_invalid_toml_are_rejected(tmp_path):
    with pytest.raises(ConfigError, match="unknown key 'trails'"):
        resolve_parameters(TOY, config=write(tmp_path, "trails = 3\n"))
    with pytest.raises(ConfigError, match="invalid TOML"):
        resolve_parameters(TOY, config=write(tmp_path, "[parameters\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        resolve_parameters(TOY, config=tmp_path / "missing.toml")


def test_sweep_refuses_a_bad_config_before_running(tmp_path):
    config = write(tmp_path, "[parameters]\nbogus = 1\n")
    with pytest.raises(ConfigError, match="'bogus'"):
        run_sweep(TOY, out=tmp_path / "out", config=config, workers=1, progress=False)
    assert not (tmp_path / "out").exists()
