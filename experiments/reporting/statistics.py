"""Statistics of stored rows: RMS, signed maxima, ratios to bounds, NEES, integrity.

Rows carry the columns of :mod:`attopt.experiments.metrics` (``err_{x,y,z}_deg``,
``sigma_{x,y,z}_deg``, ``nees``, ...) and optional bound columns
``{bound}_{x,y,z}_deg``.  A row is *valid* when its ``valid`` column (if any) is
true and it has a finite error component (:func:`valid_mask`): an invalid
epoch is NaN on every axis, an axis the estimator cannot see is NaN on a
valid one (:mod:`attopt.experiments.metrics`).  The
experiments' summary columns and the reports use these functions, so a table
and the summary computed from the same rows agree.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy.stats import chi2

AXES = ("x", "y", "z")
ERROR_COLUMNS = tuple(f"err_{a}_deg" for a in AXES)
INTEGRITY_PROBABILITY = 1e-4
"""Tail probability of the chi-square(3) quantile a row's NEES is tested against."""
NEES_DOF = 3
"""Degrees of freedom of the attitude NEES (``nees``)."""


def valid_mask(rows: pd.DataFrame) -> np.ndarray:
    """Which rows have a valid attitude: finite error components, except on the axes it
    cannot see (NaN there; module docstring)."""
    errors = rows[list(ERROR_COLUMNS)].to_numpy(dtype=float)
    valid = np.isfinite(errors).any(axis=1)
    if "valid" in rows:
        valid &= rows["valid"].fillna(False).to_numpy(dtype=bool)
    return valid


def rms(values: pd.Series) -> float:
    """Root mean square of the non-NaN ``values`` (NaN if none)."""
    finite = values.dropna().to_numpy(dtype=float)
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


def signed_max(values: pd.Series) -> float:
    """The value of largest magnitude, with its sign (NaN if none)."""
    finite = values.dropna()
    return float(finite.loc[finite.abs().idxmax()]) if len(finite) else float("nan")


def squared_norm(rows: pd.DataFrame, prefix: str = "err") -> pd.Series:
    """``x^2 + y^2 + z^2`` of the columns ``{prefix}_{x,y,z}_deg`` (NaN if any is NaN or
    the rows lack them)."""
    if f"{prefix}_x_deg" not in rows:
        return pd.Series(np.nan, index=rows.index)
    return sum(rows[f"{prefix}_{a}_deg"] ** 2 for a in AXES)


def total_rms(rows: pd.DataFrame, prefix: str = "err") -> float:
    """``sqrt(mean(x^2 + y^2 + z^2))`` of ``{prefix}_{x,y,z}_deg`` (NaN without rows)."""
    return float(np.sqrt(squared_norm(rows, prefix).mean())) if len(rows) else float("nan")


def finite_bound(rows: pd.DataFrame, bound: str = "bound") -> np.ndarray:
    """Which rows have a finite bound ``{bound}_{x,y,z}_deg`` on all three axes."""
    return np.isfinite(rows[[f"{bound}_{a}_deg" for a in AXES]].to_numpy(dtype=float)).all(axis=1)


def bounded_valid_rows(rows: pd.DataFrame, bound: str = "bound") -> pd.DataFrame:
    """Valid rows whose bound is finite on all three axes."""
    return rows[valid_mask(rows) & finite_bound(rows, bound)]


def rms_ratio(rows: pd.DataFrame, bound: str = "bound") -> float:
    """``sqrt(mean |e|^2) / sqrt(mean |b|^2)``: total RMS error over the RMS of the bound
    ``{bound}_{x,y,z}_deg`` (e.g. the Cramer-Rao bound's sqrt of the trace); NaN if empty."""
    if not len(rows):
        return float("nan")
    return float(np.sqrt(squared_norm(rows, "err").mean() / squared_norm(rows, bound).mean()))


def rms_ratio_by_group(
    rows: pd.DataFrame, by: list[str] | pd.Series, bound: str = "bound"
) -> pd.Series:
    """:func:`rms_ratio` per group of ``rows`` (columns ``by`` or an aligned Series)."""
    work = rows.assign(_e2=squared_norm(rows, "err"), _b2=squared_norm(rows, bound))
    means = work.groupby(by)[["_e2", "_b2"]].mean()
    return np.sqrt(means["_e2"] / means["_b2"])


def rms_ratio_standard_error(rows: pd.DataFrame, bound: str = "bound") -> float:
    """Standard error of :func:`rms_ratio` from the scatter of ``|e|^2`` (delta method,
    independent rows, the bound a fixed function of the geometry)."""
    if len(rows) < 2:
        return float("nan")
    error2 = squared_norm(rows, "err")
    relative = error2.std(ddof=1) / np.sqrt(len(error2)) / error2.mean()
    return 0.5 * rms_ratio(rows, bound) * float(relative)


def inside_3_sigma(rows: pd.DataFrame) -> float:
    """Share of ``rows`` whose error lies within 3 of its own sigma on all three axes."""
    if not len(rows):
        return float("nan")
    inside = np.logical_and.reduce(
        [(rows[f"err_{a}_deg"].abs() <= 3 * rows[f"sigma_{a}_deg"]).to_numpy() for a in AXES]
    )
    return float(np.mean(inside))


def error_summary(rows: pd.DataFrame) -> dict[str, float]:
    """Over the valid ``rows``: ``rms_{x,y,z}`` and ``mean_{x,y,z}`` of the body-axis
    errors, ``total_rms``, ``mean_nees`` and ``median_nees``, ``inside_3_sigma``; and
    ``valid_fraction``, the valid share of all ``rows``."""
    mask = valid_mask(rows)
    valid = rows[mask]
    out = {"valid_fraction": float(np.mean(mask)) if len(rows) else float("nan")}
    for axis in AXES:
        out[f"rms_{axis}"] = rms(valid[f"err_{axis}_deg"])
        out[f"mean_{axis}"] = float(valid[f"err_{axis}_deg"].mean())
    nees = valid["nees"] if "nees" in valid else pd.Series(np.nan, index=valid.index)
    out |= {"total_rms": total_rms(valid), "mean_nees": nees.mean(), "median_nees": nees.median()}
    return out | {"inside_3_sigma": inside_3_sigma(valid)}


def paired(
    a: pd.DataFrame, b: pd.DataFrame, keys: Sequence[str] = ("trial_index", "t")
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The rows of ``a`` and of ``b`` at the ``keys`` both have, in the same order."""
    keys = list(keys)
    index = pd.MultiIndex.from_frame(a[keys].merge(b[keys], on=keys))
    return a.set_index(keys).loc[index].reset_index(), b.set_index(keys).loc[index].reset_index()


def nees_threshold(probability: float = INTEGRITY_PROBABILITY, dof: int = NEES_DOF) -> float:
    """The chi-square(``dof``) quantile exceeded with ``probability`` (21.1 for 1e-4, 3 dof)."""
    return float(chi2.isf(probability, dof))


def integrity(
    rows: pd.DataFrame, by: Sequence[str], probability: float = INTEGRITY_PROBABILITY
) -> pd.DataFrame:
    """Per group of the columns ``by`` (at least one, e.g. the setting columns and
    ``method``): how often the estimator's covariance fails to cover its error.

    Columns (index: the groups, in order of appearance):

    * ``epochs``: rows of the group; ``valid_fraction``: share of them valid (:func:`valid_mask`);
    * ``nees_epochs``: valid rows with a finite ``nees`` (the NEES ``e^T P^-1 e``
      against the estimator's own covariance ``P``, over the row's ``nees_dof``
      axes when the rows have that column, else over 3);
    * ``share_beyond``: share of those whose NEES exceeds :func:`nees_threshold`
      of its degrees of freedom (``probability`` for a consistent estimator with
      Gaussian errors);
    * ``mean_nees`` (the degrees of freedom for a consistent one).

    Without a ``nees`` column, or where a group has no finite NEES (a method
    without a covariance), ``share_beyond`` and ``mean_nees`` are NaN.

    Example::

        >>> import pandas as pd
        >>> from attopt.experiments.reporting.statistics import integrity
        >>> rows = pd.DataFrame({
        ...     "method": ["a", "a", "b", "b"], "valid": True, "err_x_deg": 0.1, "err_y_deg": 0.1,
        ...     "err_z_deg": 0.1,
        ...     "nees": [2.0, 25.0, 2.0, 19.0], "nees_dof": [3, 3, 3, 2],
        ... })
        >>> integrity(rows, ["method"])["share_beyond"].tolist()  # 21.1 (3 dof), 18.4 (2)
        [0.5, 0.5]
    """
    by = list(by)
    valid = valid_mask(rows)
    nees = rows["nees"].to_numpy(dtype=float) if "nees" in rows else np.full(len(rows), np.nan)
    nees = np.where(valid, nees, np.nan)
    judged = np.isfinite(nees)
    dof = rows["nees_dof"].to_numpy(dtype=float) if "nees_dof" in rows else NEES_DOF
    beyond = np.where(judged, nees > chi2.isf(probability, dof), np.nan)
    work = rows[by].assign(_valid=valid, _judged=judged, _nees=nees, _beyond=beyond)
    groups = work.groupby(by, sort=False, dropna=False)
    return pd.DataFrame(
        {
            "epochs": groups.size(),
            "valid_fraction": groups["_valid"].mean(),
            "nees_epochs": groups["_judged"].sum().astype(int),
            "share_beyond": groups["_beyond"].mean(),
            "mean_nees": groups["_nees"].mean(),
        }
    )


def reason_class(reason: str) -> str:
    """The kind of a flag: a reason's text before its first ``": "`` (the details after it,
    thresholds and counts, vary), e.g. ``"lost track"`` or ``"model mismatch"``."""
    return reason.split(": ", 1)[0].strip() or "(no reason given)"


def flagged_by_reason(rows: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Per group of the columns ``by``: the share of its epochs flagged (not valid,
    :func:`valid_mask`) for each kind of reason (:func:`reason_class` of the ``reason``
    column); one column per kind, ordered by how many epochs it flags in all, and
    ``flagged``, their sum.  Groups without a flagged epoch have zeros.

    Example::

        >>> import pandas as pd
        >>> from attopt.experiments.reporting.statistics import flagged_by_reason
        >>> rows = pd.DataFrame({
        ...     "method": ["a", "a", "a", "b"], "valid": [True, False, False, False],
        ...     "err_x_deg": 0.1, "err_y_deg": 0.1, "err_z_deg": 0.1,
        ...     "reason": ["", "lost track: 5 epochs", "lost track: 6 epochs", "model mismatch: x"],
        ... })
        >>> flagged_by_reason(rows, ["method"]).round(3).to_dict("index")
        {'a': {'lost track': 0.667, 'model mismatch': 0.0, 'flagged': 0.667}, \
'b': {'lost track': 0.0, 'model mismatch': 1.0, 'flagged': 1.0}}
    """
    by = list(by)
    flagged = ~valid_mask(rows)
    reasons = rows["reason"] if "reason" in rows else pd.Series("", index=rows.index)
    kinds = reasons[flagged].fillna("").astype(str).map(reason_class).rename("_kind")
    counts = rows.loc[flagged, by].assign(_kind=kinds)
    counts = counts.groupby([*by, "_kind"], dropna=False).size().unstack("_kind")
    epochs = rows.groupby(by, sort=False, dropna=False).size()
    counts = counts.reindex(epochs.index).fillna(0)
    order = counts.sum().sort_values(ascending=False, kind="stable").index
    shares = counts[order].div(epochs, axis=0).astype(float)
    shares.columns = list(shares.columns)
    return shares.assign(flagged=shares.sum(axis=1))


def nees_interval(
    trials: int, dimension: int = NEES_DOF, probability: float = 0.95
) -> tuple[float, float]:
    """Two-sided ``probability`` interval of a NEES averaged over ``trials`` runs:
    ``chi2(dimension * trials) / trials`` (Bar-Shalom et al. 2001, sec. 5.4)."""
    tail = (1.0 - probability) / 2.0
    dof = dimension * trials
    return float(chi2.ppf(tail, dof) / trials), float(chi2.ppf(1.0 - tail, dof) / trials)


def run_averaged_nees(rows: pd.DataFrame, time: str = "t") -> pd.Series:
    """Per epoch (column ``time``), the NEES averaged over the trials (epochs present in all
    of them)."""
    trials = rows["trial_index"].nunique()
    by_epoch = rows.groupby(time)["nees"]
    return by_epoch.mean()[by_epoch.count() == trials]
