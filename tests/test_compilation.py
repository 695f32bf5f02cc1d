"""The numba loops' warm-ups: every loop has one, and they compile what the work calls."""

from __future__ import annotations

import importlib
import multiprocessing
import re
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numba.core.registry import CPUDispatcher
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.config import resolve_parameters
from attopt.experiments.registry import get_experiment
from attopt.solvers.compilation import LOOP_MODULES, compile_loops, loop_names

PARTS = ("attopt.formulations", "attopt.solvers")


def dispatchers() -> dict[str, CPUDispatcher]:
    """Every numba function defined at the top of a loop module, by qualified name, but
    those inlined into their callers (the Wahba loops' helpers), which have no signature
    of their own."""
    found = {}
    for name in LOOP_MODULES:
        module = importlib.import_module(name)
        for attribute, value in vars(module).items():
            if (
                isinstance(value, CPUDispatcher)
                and value.__module__ == name
                and value.targetoptions.get("inline") != "always"
            ):
                found[f"{name}.{attribute}"] = value
    return found


def signatures() -> dict[str, list]:
    return {name: list(d.signatures) for name, d in dispatchers().items()}


def test_every_module_with_numba_loops_is_listed():
    jitted = set()
    for part in PARTS:
        root = Path(importlib.import_module(part).__file__).parent
        for path in root.rglob("*.py"):
            if re.search(r"\bnjit\(", path.read_text()):
                jitted.add(".".join((part, *path.relative_to(root).with_suffix("").parts)))
    assert jitted == set(LOOP_MODULES)


def loops() -> dict[str, CPUDispatcher]:
    """The numba loops called through ``first_call`` (or the filters' ``run_loop``, which
    calls it) in the loop modules' source, by qualified name (a tuple of loops, as the
    Wahba solvers' ``_SOLVE``, one by one)."""
    found = {}
    for name in LOOP_MODULES:
        module = importlib.import_module(name)
        source = Path(module.__file__).read_text()
        for called in re.findall(r"(?:first_call|run_loop)\(\s*(\w+)", source):
            if called == "loop":  # run_loop's own call of the loop it is given
                continue
            value = getattr(module, called)
            for i, loop in enumerate(value if isinstance(value, tuple) else (value,)):
                found[f"{name}.{called}[{i}]"] = loop
    return found


def test_the_warm_ups_compile_every_loop():
    compile_loops()
    found = loops()
    assert len(found) == len(loop_names())
    assert not [name for name, loop in found.items() if not loop.signatures]


def test_a_trial_after_its_experiments_warm_ups_compiles_nothing_more():
    experiment = get_experiment("wahba-mag-sun")
    compile_loops(experiment.compiled_loops)
    before = signatures()
    overrides = {"duration_s": 120.0, "step_s": 1.0}
    parameters = resolve_parameters(experiment, overrides=overrides).model_dump(mode="json")
    setting = experiment.grid(parameters)[0]
    rows = experiment.trial(setting, np.random.SeedSequence(0))
    assert set(pd.DataFrame(rows)["method"]) >= {"quest", "mekf", "usque", "fg_batch"}
    assert signatures() == before


def test_loops_are_chosen_by_name_or_prefix_and_unknown_names_rejected():
    names = loop_names(["wahba", "filters.gate"])
    assert names[:5] == [f"wahba.{m}" for m in ("foam", "q_method", "quest", "svd", "triad")]
    assert names[5:] == ["filters.gate"]
    assert loop_names([]) == []
    with pytest.raises(KeyError, match=r"wahba\.lost"):
        loop_names(["wahba.lost"])


def test_a_pool_compiles_each_loop_in_one_of_its_workers():
    names = loop_names(["smoother"])
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=2, mp_context=context) as pool:
        seconds = compile_loops(["smoother"], pool)
    assert list(seconds) == names
    assert all(s >= 0.0 for s in seconds.values())


def test_the_compile_command_lists_each_loop_and_rejects_unknown_names():
    done = CliRunner().invoke(app, ["compile", "smoother", "--workers", "1"])
    assert done.exit_code == 0, done.output
    lines = done.output.splitlines()
    assert [line.split()[0] for line in lines[:-1]] == loop_names(["smoother"])
    assert lines[-1].startswith("3 loops ready in")
    unknown = CliRunner().invoke(app, ["compile", "wahba.lost"])
    assert unknown.exit_code == 2 and "no numba loop named 'wahba.lost'" in unknown.output
