"""``attopt check OUT_DIR``: the integrity statistic of any results directory.

A sweep's directory (``manifest.json`` and ``rows/``, :mod:`attopt.experiments.sweep.store`)
is grouped as its report groups it: the setting columns that vary, then the
experiment's ``group_by`` (:func:`integrity_groups`); a directory of ``attopt
estimate`` (``rows.parquet``) by ``method``.  The statistic is
:func:`attopt.experiments.reporting.statistics.integrity`: per group, the share of
valid epochs whose NEES exceeds the chi-square 1 - 1e-4 quantile, the mean NEES
and the valid fraction.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from attopt.experiments.reporting.integrity import integrity_table
from attopt.experiments.sweep.store import MANIFEST, ROWS_DIR
from attopt.experiments.sweep.tasks import load_experiment, setting_columns

ESTIMATE_ROWS = "rows.parquet"
"""The rows file of an ``attopt estimate`` directory."""


class ResultsError(ValueError):
    """A directory that holds no readable results."""


def integrity_groups(
    rows: pd.DataFrame, setting_columns: Sequence[str], group_by: Sequence[str]
) -> list[str]:
    """The columns a report's integrity section groups by: the setting columns whose value
    varies over ``rows``, then ``group_by``."""
    varying = [c for c in setting_columns if c in rows and rows[c].nunique(dropna=False) > 1]
    return [*varying, *group_by]


def results_rows(out: Path) -> tuple[pd.DataFrame, list[str]]:
    """The rows of results directory ``out`` and the columns to group them by.

    Raises:
        ResultsError: no ``manifest.json`` with ``rows/`` and no ``rows.parquet``, or a
            rows file that cannot be read.
    """
    out = Path(out)
    try:
        if (out / ESTIMATE_ROWS).is_file():
            return pd.read_parquet(out / ESTIMATE_ROWS), ["method"]
        if not (out / MANIFEST).is_file():
            raise ResultsError(f"{out}: no {MANIFEST} or {ESTIMATE_ROWS}: not a results directory")
        manifest = json.loads((out / MANIFEST).read_text())
        experiment = load_experiment(manifest["reference"])
        files = sorted((out / ROWS_DIR).glob("*.parquet"))
        if not files:
            raise ResultsError(f"{out}: no rows yet (no {ROWS_DIR}/*.parquet)")
        rows = pd.concat([pd.read_parquet(path) for path in files], ignore_index=True)
    except (OSError, ValueError, KeyError) as error:
        if isinstance(error, ResultsError):
            raise
        raise ResultsError(f"{out}: cannot read the results: {error}") from None
    columns = setting_columns(manifest["settings"])
    return rows, integrity_groups(rows, columns, experiment.group_by)


def check(out: Path) -> pd.DataFrame:
    """The integrity table of results directory ``out`` (module docstring).

    Example::

        >>> import tempfile
        >>> from pathlib import Path
        >>> from attopt.experiments.sweep import run_sweep
        >>> from attopt.experiments.sweep.check import check
        >>> from attopt.experiments.sweep.toys import NOOP
        >>> out = Path(tempfile.mkdtemp())
        >>> _ = run_sweep(NOOP, trials=2, out=out, workers=1, progress=False)
        >>> check(out).columns.tolist()[-4:]
        ['valid', 'valid epochs with a NEES', 'share beyond 21.1', 'mean NEES']
    """
    rows, by = results_rows(out)
    return integrity_table(rows, by)
