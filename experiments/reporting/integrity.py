"""The integrity section every report ends its tables with
(:func:`attopt.experiments.reporting.statistics.integrity` as markdown)."""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

from attopt.experiments.reporting.statistics import (
    INTEGRITY_PROBABILITY,
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


def integrity_section(rows: pd.DataFrame, by: Sequence[str], command: str = "") -> str:
    """``## Integrity``: per group of ``by``, the share of valid epochs whose NEES exceeds
    the chi-square(3) 1 - 1e-4 quantile, the mean NEES and the valid fraction."""
    threshold = nees_threshold()
    table = integrity_table(rows, by)
    caption = (
        "How often each estimator's own covariance fails to cover its error: over its valid "
        "epochs with a NEES (3-dof, `nees`), the share beyond the chi-square(3) "
        f"{1 - INTEGRITY_PROBABILITY:g} quantile ({threshold:.1f}; {INTEGRITY_PROBABILITY:g} "
        "for a consistent estimator), the mean NEES (3) and the valid share of all its epochs. "
        f"{NOT_AVAILABLE}: no NEES in the rows (no covariance)." + made_by(command)
    )
    formats = {
        "valid": ".3f",
        f"share beyond {threshold:.1f}": ".3g",
        "mean NEES": ".3g",
    }
    return section("Integrity", caption, markdown_table(table, formats, missing=NOT_AVAILABLE))
