"""Markdown tables from DataFrames with one number format, and the parts of a report.

Numbers: floats with a format spec per column (default 4 significant digits),
integers as they are, missing values (NaN, None) as ``-`` unless a table says
otherwise.  Several numbers in one cell (roll / pitch / yaw) come from
:func:`joined`.  A paper's values beside ours: :func:`with_paper`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

FLOAT_FORMAT = ".4g"
MISSING = "-"


def cell(value: Any, spec: str = FLOAT_FORMAT, missing: str = MISSING) -> str:
    """``value`` as the text of one markdown cell."""
    if value is None or value is pd.NA:
        return missing
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return missing if np.isnan(value) else format(float(value), spec)
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(
    frame: pd.DataFrame,
    formats: Mapping[str, str] | None = None,
    spec: str = FLOAT_FORMAT,
    missing: str = MISSING,
) -> str:
    """``frame`` as a GitHub markdown table; ``formats`` maps columns to format specs."""
    formats = formats or {}
    header = [str(column) for column in frame.columns]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in frame.itertuples(index=False):
        cells = (
            cell(value, formats.get(column, spec), missing)
            for column, value in zip(frame.columns, row, strict=True)
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def joined(
    frame: pd.DataFrame,
    columns: Sequence[str],
    spec: str = ".3f",
    missing: str = MISSING,
    sep: str = " / ",
) -> pd.Series:
    """Per row, the values of ``columns`` formatted with ``spec`` and joined by ``sep``
    (e.g. ``"0.187 / 0.405 / 0.238"``); ``missing`` alone when all are missing."""
    values = frame[list(columns)].to_numpy(dtype=float)
    return pd.Series(
        [
            sep.join(cell(v, spec, missing) for v in row) if np.isfinite(row).any() else missing
            for row in values
        ],
        index=frame.index,
        dtype=object,
    )


def with_paper(
    ours: pd.DataFrame, paper: pd.DataFrame, on: Sequence[str], label: str
) -> pd.DataFrame:
    """``ours`` with the columns of ``paper`` joined on ``on``, each named
    ``"{column} ({label})"`` (e.g. ``"RMS roll / pitch / yaw (Cilden Guler et al. 2017
    Table 1)"``); rows the paper does not have get missing values."""
    renamed = paper.rename(columns={c: f"{c} ({label})" for c in paper.columns if c not in on})
    return ours.merge(renamed, on=list(on), how="left")


def made_by(command: str) -> str:
    """The caption's last sentence naming the command that made the rows."""
    return f" From `{command}`." if command else ""


def section(title: str, *parts: str, level: int = 2) -> str:
    """A markdown section: the heading, then ``parts`` (captions, tables) as paragraphs."""
    body = "\n\n".join(part.strip("\n") for part in parts if part)
    return f"{'#' * level} {title}\n\n{body}\n"


def document(sections: Iterable[str]) -> str:
    """The sections joined into one markdown document."""
    return "\n".join(s for s in sections if s)
