"""What an experiment declares to the sweep runner.

An experiment is plain data plus two top-level (picklable) functions:

* ``grid(parameters)`` expands the parameters into a list of *settings*
  (plain dicts, e.g. one per input SNR x snapshot count);
* ``trial(setting, seed)`` simulates one Monte Carlo trial of one setting from
  ``seed`` (a :class:`numpy.random.SeedSequence` derived per trial by the
  runner) and returns rows of metrics, one per method (and per group such as
  an eclipse interval or an epoch).  Every method in a trial sees the same
  simulated data.

Row columns understood by the aggregation:

* ``method`` (str), and the experiment's ``group_by`` columns;
* ``err_x_deg``, ``err_y_deg``, ``err_z_deg``: body-axis components of the
  attitude error (roll, pitch, yaw axes), NaN where the method gave no valid
  attitude;
* ``valid`` (bool) and ``reason`` (str, empty when valid);
* optional ``bound_x_deg``, ``bound_y_deg``, ``bound_z_deg``: the standard
  deviation a bound (e.g. the Cramer-Rao bound or the method's own
  covariance) predicts for that row, for RMS-to-bound ratios.

An experiment may add its own summary columns with ``summary_columns``: a
function of the stored rows grouped by the summary keys (setting columns and
``group_by``) returning one row per group; its columns are joined to
``summary.csv`` (e.g. signed maximum errors or run times).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from attopt.experiments.config.schema import Parameters

Setting = dict[str, Any]
Row = dict[str, Any]


@dataclass(frozen=True)
class ReportContext:
    """What an experiment's report hook receives after a sweep (``command``: the command
    line that reproduces it, for the tables' captions)."""

    parameters: Mapping[str, Any]
    rows: pd.DataFrame
    summary: pd.DataFrame
    out_dir: Path
    command: str = ""


@dataclass(frozen=True)
class Experiment:
    """A named Monte Carlo experiment the runner can execute.

    ``schema`` is the pydantic model of its parameters (defaults, units, meanings);
    ``quick_parameters`` a (nested) document of overrides for ``--quick``.  ``grid``
    receives the validated parameters as a plain document
    (``model_dump(mode="json")``: nested tables are dicts, arrays lists).
    ``compiled_loops`` names the numba loops its estimators call (entries of
    :func:`attopt.solvers.compilation.loop_names`): the sweep's workers compile them, each
    loop in one worker, before the first trial (a loop not named is compiled where it is
    first called, by every worker that reaches it first).
    """

    name: str
    summary: str
    schema: type[Parameters]
    grid: Callable[[Mapping[str, Any]], list[Setting]]
    trial: Callable[[Setting, np.random.SeedSequence], list[Row]]
    default_trials: int
    quick_trials: int
    quick_parameters: Mapping[str, Any] = field(default_factory=dict)
    group_by: tuple[str, ...] = ("method",)
    report: Callable[[ReportContext], str] | None = None
    summary_columns: Callable[[pd.DataFrame, list[str]], pd.DataFrame] | None = None
    compiled_loops: tuple[str, ...] = ()

    @property
    def parameters(self) -> dict[str, Any]:
        """The default parameters as a plain document (what ``grid`` receives unchanged)."""
        return self.schema().model_dump(mode="json")
