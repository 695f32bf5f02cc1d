"""A no-op experiment for checking a cluster and measuring the runner's overhead.

Its trial draws three tiny random "errors" and optionally sleeps; it computes
nothing else.  ``attopt run noop --quick --engine dask --address ...`` checks
that a Dask cluster can import and run attopt; ``attopt bench runner`` times it.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import Field

from attopt.experiments.config.schema import Parameters
from attopt.experiments.experiment import Experiment, Row, Setting


class NoopParameters(Parameters):
    """Parameters of the no-op experiment."""

    settings: int = Field(4, ge=1, description="Number of settings (each the same trial).")
    sleep_s: float = Field(0.0, ge=0.0, description="Time each trial sleeps.")


def noop_grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per index, each carrying the trial's sleep time."""
    return [
        {"setting": index, "sleep_s": parameters["sleep_s"]}
        for index in range(parameters["settings"])
    ]


def noop_trial(setting: Setting, seed: np.random.SeedSequence) -> list[Row]:
    """Sleep ``setting["sleep_s"]`` seconds and return one row of random errors."""
    if setting["sleep_s"] > 0:
        time.sleep(setting["sleep_s"])
    errors = np.random.default_rng(seed).normal(scale=1e-3, size=3)
    return [
        {
            "method": "noop",
            "err_x_deg": float(errors[0]),
            "err_y_deg": float(errors[1]),
            "err_z_deg": float(errors[2]),
            "valid": True,
            "reason": "",
        }
    ]


NOOP = Experiment(
    name="noop",
    summary="No-op trial (random numbers only): checks a cluster and times the runner.",
    schema=NoopParameters,
    grid=noop_grid,
    trial=noop_trial,
    default_trials=1000,
    quick_trials=25,
)
