"""Per-setting, per-method statistics of the attitude errors of a sweep.

A row counts as valid when its ``valid`` column (if any) is true and it has a
finite error component; an axis the estimator cannot see is NaN on a valid
row (:func:`attopt.experiments.reporting.statistics.valid_mask`).  RMS, means
and percentiles are over valid rows, per axis over those with a finite error
on it, so an axis that is NaN in every row of a group is NaN (never 0) in
each of its summary columns; the error angle is the norm of the error
rotation vector over the axes it has.  When the rows carry
``bound_{x,y,z}_deg`` (predicted standard deviations), the RMS of the bound
over the valid rows and the ratio RMS / bound are added per axis.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from attopt.experiments.reporting.statistics import valid_mask

AXES = (
    ("roll", "err_x_deg", "bound_x_deg"),
    ("pitch", "err_y_deg", "bound_y_deg"),
    ("yaw", "err_z_deg", "bound_z_deg"),
)
ERROR_COLUMNS = tuple(error for _, error, _ in AXES)
PERCENTILES = (50, 95)
MAX_REASONS = 20


def summarise(
    rows: pd.DataFrame,
    failures: pd.DataFrame,
    *,
    setting_columns: Sequence[str],
    group_by: Sequence[str],
    extra: Callable[[pd.DataFrame, list[str]], pd.DataFrame] | None = None,
) -> pd.DataFrame:
    """Return one summary row per setting and ``group_by`` group (e.g. per method).

    Columns: the setting index and columns, the group columns, ``n_rows``,
    ``n_valid``, ``valid_fraction``, ``{roll,pitch,yaw}_rms_deg``,
    ``total_rms_deg``, ``{roll,pitch,yaw}_mean_deg``, ``p50_deg``, ``p95_deg``,
    ``failed_trials`` (trials of the setting that raised) and, with bounds,
    ``{axis}_bound_deg`` and ``{axis}_ratio``, then the columns ``extra(rows,
    keys)`` returns per group (an experiment's ``summary_columns``).  Settings
    whose every trial failed appear with ``n_rows == 0``.
    """
    keys = list(dict.fromkeys(["setting_index", *setting_columns, *group_by]))
    if len(rows):
        summary = _error_statistics(rows, keys)
        if extra is not None:
            summary = summary.merge(extra(rows, keys), on=keys, how="left")
    else:
        summary = pd.DataFrame(columns=[*keys, "n_rows", "n_valid"])
    failed = failures.groupby("setting_index").size() if len(failures) else pd.Series(dtype=int)
    lost = failures[~failures["setting_index"].isin(summary["setting_index"])]
    if len(lost):
        lost = lost.drop_duplicates("setting_index")
        lost = lost[[c for c in keys if c in lost.columns]].assign(n_rows=0, n_valid=0)
        summary = pd.concat([summary, lost], ignore_index=True)
    summary["failed_trials"] = summary["setting_index"].map(failed).fillna(0).astype(int)
    summary = summary.sort_values("setting_index", kind="stable")
    return summary.reset_index(drop=True)


def invalid_reasons(rows: pd.DataFrame, group_by: Sequence[str]) -> pd.DataFrame:
    """Return the most common reasons of invalid rows, counted per group."""
    columns = [*group_by, "reason", "rows"]
    if not len(rows):
        return pd.DataFrame(columns=columns)
    invalid = rows.loc[~valid_mask(rows), list(group_by)].copy()
    if "reason" in rows:
        reasons = rows.loc[invalid.index, "reason"].fillna("").astype(str)
    else:
        reasons = pd.Series("", index=invalid.index)
    invalid["reason"] = reasons.where(reasons != "", "(no reason given)")
    counts = invalid.groupby([*group_by, "reason"], dropna=False).size().rename("rows")
    counts = counts.reset_index().sort_values("rows", ascending=False, kind="stable")
    return counts.head(MAX_REASONS).reset_index(drop=True)[columns]


def _error_statistics(rows: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    missing = [column for column in (*keys, *ERROR_COLUMNS) if column not in rows]
    if missing:
        raise ValueError(f"rows lack the column(s) {missing} needed for the summary")
    valid = valid_mask(rows)
    errors = np.where(valid[:, None], rows[list(ERROR_COLUMNS)].to_numpy(dtype=float), np.nan)
    work = rows[keys].copy()
    work["valid"] = valid
    bounded = []
    for axis, (name, _, bound) in enumerate(AXES):
        work[f"{name}_mean_deg"] = errors[:, axis]
        work[f"{name}_ms"] = errors[:, axis] ** 2
        if bound in rows:
            bounded.append(name)
            sigma = rows[bound].to_numpy(dtype=float)
            work[f"{name}_bound_ms"] = np.where(valid, sigma**2, np.nan)
    angle = np.where(valid, np.sqrt(np.nansum(errors**2, axis=1)), np.nan)
    work["angle"] = angle
    work["total_ms"] = angle**2
    groups = work.groupby(keys, dropna=False, sort=True)
    means = groups[[c for c in work.columns if c.endswith(("_ms", "_mean_deg"))]].mean()
    summary = pd.DataFrame({"n_rows": groups.size(), "n_valid": groups["valid"].sum().astype(int)})
    summary["valid_fraction"] = summary["n_valid"] / summary["n_rows"]
    for name, _, _ in AXES:
        summary[f"{name}_rms_deg"] = np.sqrt(means[f"{name}_ms"])
    summary["total_rms_deg"] = np.sqrt(means["total_ms"])
    for name, _, _ in AXES:
        summary[f"{name}_mean_deg"] = means[f"{name}_mean_deg"]
    for percentile in PERCENTILES:
        summary[f"p{percentile}_deg"] = groups["angle"].quantile(percentile / 100)
    for name in bounded:
        summary[f"{name}_bound_deg"] = np.sqrt(means[f"{name}_bound_ms"])
    for name in bounded:
        summary[f"{name}_ratio"] = summary[f"{name}_rms_deg"] / summary[f"{name}_bound_deg"]
    return summary.reset_index()
