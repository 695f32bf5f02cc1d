"""The integrity section every report ends its tables with: the integrity statistic
(:func:`attopt.experiments.reporting.statistics.integrity`) and the epochs flagged by
kind of reason (:func:`~attopt.experiments.reporting.statistics.flagged_by_reason`),
as markdown."""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

from attopt.experiments.reporting.statistics import (
    INTEGRITY_PROBABILITY,
    flagged_by_reason,
    integrity,
    nees_threshold,
)
from attopt.experiments.reporting.tables import made_by, markdown_table, section

NOT_AVAILABLE = "n/a"


def integrity_table(rows: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """The integrity statistic per group of ``by`` with the report's column names."""
    table = integrity(rows, by).reset_index()
    threshold = nees_threshold()
    return table.rename(
        columns={
            "valid_fraction": "valid",
            "nees_epochs": "valid epochs with a NEES",
            "share_beyond": f"share beyond {threshold:.1f}",
            "mean_nees": "mean NEES",
        }
    )


def flagged_table(rows: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """:func:`~attopt.experiments.reporting.statistics.flagged_by_reason` with the group
    columns ``by`` as columns: per group, the share of its epochs flagged for each kind of
    reason, and in all."""
    return flagged_by_reason(rows, by).reset_index()


def worst_share(rows: pd.DataFrame, by: Sequence[str]) -> tuple[float, str]:
    """The largest share beyond the quantile over the groups of ``by``
    (:func:`~attopt.experiments.reporting.statistics.integrity`) and its group, as
    ``"key=value, ..."``; ``(nan, "")`` when no group has a NEES (or there are no rows).

    Example::

        >>> import pandas as pd
        >>> from attopt.experiments.reporting.integrity import worst_share
        >>> rows = pd.DataFrame({
        ...     "method": ["a", "a", "b", "b"], "valid": True, "err_x_deg": 0.1, "err_y_deg": 0.1,
        ...     "err_z_deg": 0.1,
        ...     "nees": [2.0, 25.0, 2.0, 3.0],
        ... })
        >>> worst_share(rows, ["method"])
        (0.5, 'method=a')
    """
    by = list(by)
    if rows.empty:
        return float("nan"), ""
    shares = integrity(rows, by)["share_beyond"]
    if not shares.notna().any():
        return float("nan"), ""
    group = shares.idxmax()
    values = group if isinstance(group, tuple) else (group,)
    label = ", ".join(f"{key}={value}" for key, value in zip(by, values, strict=True))
    return float(shares.max()), label


def integrity_section(rows: pd.DataFrame, by: Sequence[str], command: str = "") -> str:
    """``## Integrity``: per group of ``by``, the share of valid epochs whose NEES exceeds
    the chi-square(3) 1 - 1e-4 quantile, the mean NEES and the valid fraction; a line
    saying there is none without rows (every trial failed)."""
    if rows.empty:
        return section("Integrity", "No rows: no trial finished without an exception.")
    threshold = nees_threshold()
    table = integrity_table(rows, by)
    caption = (
        "How often each estimator's own covariance fails to cover its error: over its valid "
        "epochs with a NEES (`nees`, over 3 axes or the row's `nees_dof`), the share beyond "
        f"the chi-square {1 - INTEGRITY_PROBABILITY:g} quantile of its degrees of freedom "
        f"({threshold:.1f} for 3; {INTEGRITY_PROBABILITY:g} for a consistent estimator), the "
        "mean NEES (its degrees of freedom) and the valid share of all its epochs. "
        f"{NOT_AVAILABLE}: no NEES in the rows (no covariance)." + made_by(command)
    )
    formats = {
        "valid": ".3f",
        f"share beyond {threshold:.1f}": ".3g",
        "mean NEES": ".3g",
    }
    flagged = flagged_table(rows, by)
    reasons = [c for c in flagged.columns if c not in by]
    flagged_caption = (
        "Epochs flagged, by kind of reason: the share of each group's epochs that the "
        "estimator reports as not valid (the reason's text before its details; the rows' "
        "`reason` column has it whole)."
    )
    return section(
        "Integrity",
        caption,
        markdown_table(table, formats, missing=NOT_AVAILABLE),
        flagged_caption,
        markdown_table(flagged, dict.fromkeys(reasons, ".3g")),
    )
