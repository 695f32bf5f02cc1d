"""Read the markdown tables of a generated report back into DataFrames (for report tests)."""

from __future__ import annotations

from collections.abc import Mapping

import pandas as pd


def table(text: str, heading: str, index: int = 0) -> pd.DataFrame:
    """The ``index``-th markdown table after the heading line ending in ``heading``, as strings."""
    lines = text.splitlines()
    start = next(
        i for i, line in enumerate(lines) if line.startswith("#") and line.endswith(heading)
    )
    found = -1
    for i in range(start + 1, len(lines)):
        if lines[i].startswith("|") and not lines[i - 1].startswith("|"):
            found += 1
            if found == index:
                block = _block(lines, i)
                header = _cells(block[0])
                return pd.DataFrame([_cells(row) for row in block[2:]], columns=header)
    raise LookupError(f"no table {index} after {heading!r}")


def row(frame: pd.DataFrame, where: Mapping[str, str]) -> pd.Series:
    """The one row of ``frame`` whose columns equal the texts of ``where``."""
    keep = pd.Series(True, index=frame.index)
    for column, value in where.items():
        keep &= frame[column] == value
    (match,) = frame.index[keep]
    return frame.loc[match]


def _block(lines: list[str], start: int) -> list[str]:
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return lines[start:end]


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]
