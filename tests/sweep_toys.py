"""Toy experiments for the sweep tests, importable by worker processes.

The trial can be instrumented from the environment (inherited by spawned
workers), so that the parameters, and hence the manifest, stay the same
between an interrupted run and its resumption:

* ``TOY_CALLS_DIR``: every trial call creates a file ``{setting}-{trial}-{uuid}``
  there, so tests can count calls across processes;
* ``TOY_STOP_FILE``: if this file exists and reads ``ACTION SETTING TRIAL``,
  that trial raises KeyboardInterrupt (``interrupt``) or kills its process
  (``exit``).
"""

from __future__ import annotations

import dataclasses
import os
import signal
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from pydantic import Field

from attopt.experiments.config import Parameters
from attopt.experiments.experiment import Experiment, ReportContext, Row, Setting


class Nested(Parameters):
    """A nested table of the toy experiment (config tests)."""

    altitude_km: float = Field(600.0, gt=0, description="A number with a unit.")
    name: str = Field("x", description="A name.")


def toy_grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per scale; non-scalar entries (methods) stay out of the row columns."""
    return [
        {
            "scale": scale,
            "label": f"scale-{scale:g}",
            "methods": list(parameters["methods"]),
            "rows": parameters["rows_per_trial"],
            "fail_every": parameters["fail_every"],
            "doomed": index == parameters["doomed_setting"],
            "as_frame": parameters["as_frame"],
        }
        for index, scale in enumerate(parameters["scales"])
    ]


def toy_trial(setting: Setting, seed: np.random.SeedSequence) -> list[Row] | pd.DataFrame:
    """Shared random data per trial; method ``i`` has errors ``(i + 1) * data``."""
    setting_index, trial_index = seed.spawn_key
    _instrument(setting_index, trial_index)
    if setting["doomed"]:
        raise RuntimeError("this setting always fails")
    if setting["fail_every"] and trial_index % setting["fail_every"] == setting["fail_every"] - 1:
        raise ValueError(f"unlucky trial {trial_index}")
    rng = np.random.default_rng(seed)
    data = setting["scale"] * rng.normal(size=(setting["rows"], 3))
    valid = np.abs(data[:, 0]) < 1.5 * setting["scale"]
    columns: dict[str, list[Any]] = {}
    for index, method in enumerate(setting["methods"]):
        errors = np.where(valid[:, None], (index + 1) * data, np.nan)
        block = {
            "method": [method] * setting["rows"],
            "epoch": list(range(setting["rows"])),
            "err_x_deg": list(errors[:, 0]),
            "err_y_deg": list(errors[:, 1]),
            "err_z_deg": list(errors[:, 2]),
            "valid": list(valid),
            "reason": ["" if v else "outlier" for v in valid],
            "bound_x_deg": [(index + 1) * setting["scale"]] * setting["rows"],
            "bound_y_deg": [(index + 1) * setting["scale"]] * setting["rows"],
            "bound_z_deg": [(index + 1) * setting["scale"]] * setting["rows"],
        }
        for key, values in block.items():
            columns.setdefault(key, []).extend(values)
    frame = pd.DataFrame(columns)
    return frame if setting["as_frame"] else frame.to_dict("records")


def _instrument(setting_index: int, trial_index: int) -> None:
    calls = os.environ.get("TOY_CALLS_DIR")
    if calls:
        (Path(calls) / f"{setting_index}-{trial_index}-{uuid.uuid4().hex}").touch()
    stop = Path(os.environ.get("TOY_STOP_FILE", "/nonexistent"))
    if stop.exists():
        action, s, t = stop.read_text().split()
        if (int(s), int(t)) == (setting_index, trial_index):
            if action == "exit":
                os._exit(3)
            raise KeyboardInterrupt


class ToyParameters(Parameters):
    """Parameters of the toy experiment."""

    scales: list[float] = Field([1.0, 2.0, 3.0], description="One setting per scale.")
    methods: list[str] = Field(["a", "b"], description="Row labels.")
    rows_per_trial: int = Field(3, ge=1, description="Rows per method and trial.")
    fail_every: int = Field(0, ge=0, description="Every k-th trial raises (0: none).")
    doomed_setting: int = Field(-1, description="Index of a setting that always fails.")
    as_frame: bool = Field(False, description="Return a DataFrame instead of rows.")
    nested: Nested = Field(Nested(), description="A nested table.")


TOY = Experiment(
    name="toy",
    summary="Random errors with shared data per trial, for the sweep tests.",
    schema=ToyParameters,
    grid=toy_grid,
    trial=toy_trial,
    default_trials=6,
    quick_trials=2,
    quick_parameters={"scales": [1.0]},
)


def toy_report(context: ReportContext) -> str:
    """Write a small file next to the report and describe what the hook received."""
    (context.out_dir / "toy-figure.txt").write_text(f"{len(context.rows)} rows\n")
    return (
        "## Toy section\n\n"
        f"{len(context.rows)} rows, {len(context.summary)} summary rows, "
        f"scales {context.parameters['scales']}.\n"
    )


TOY_WITH_REPORT = dataclasses.replace(TOY, name="toy-report", report=toy_report)


def probe_trial(setting: Setting, seed: np.random.SeedSequence) -> list[Row]:
    """Report the worker's BLAS thread variable and Ctrl-C handling as row columns, and
    whether the experiment's numba loop was ready when the trial called it (compiled in
    this process, or loaded from numba's cache, not compiled by this call)."""
    from attopt.solvers.smoother import compiled

    misses = sum(compiled._downdate.stats.cache_misses.values())
    compiled.downdate(np.zeros((2, 2)), np.ones((1, 2)))
    return [
        {
            "method": "probe",
            "omp_threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "ignores_sigint": signal.getsignal(signal.SIGINT) is signal.SIG_IGN,
            "loop_ready": sum(compiled._downdate.stats.cache_misses.values()) == misses,
            "pid": os.getpid(),
            "err_x_deg": 0.0,
            "err_y_deg": 0.0,
            "err_z_deg": 0.0,
        }
    ]


PROBE = Experiment(
    name="probe",
    summary="Reports the environment of the worker processes.",
    schema=Parameters,
    grid=lambda parameters: [{}],
    trial=probe_trial,
    default_trials=4,
    quick_trials=4,
    compiled_loops=("smoother.offsets_downdate",),
)
