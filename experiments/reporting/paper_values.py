"""The published values a report compares against, from the experiment's ``paper_values.toml``.

Each experiment package holds one ``paper_values.toml`` (package data):
``paper`` (author and year), then one TOML table per table, figure or
statement of the paper used, each with ``source`` (where in the paper, e.g.
``"Table 1"``).  A tabulated source has ``columns`` and ``rows`` (one array per
row; ``nan`` where the paper has no value); a statement has its values as
keys.
"""

from __future__ import annotations

import functools
import tomllib
from importlib import resources
from typing import Any

import pandas as pd

FILE = "paper_values.toml"


@functools.cache
def paper_values(package: str) -> dict[str, Any]:
    """The parsed ``paper_values.toml`` of the experiment package ``package``
    (e.g. ``"attopt.experiments.adsb_snr"``)."""
    return tomllib.loads(resources.files(package).joinpath(FILE).read_text())


def paper_table(package: str, name: str) -> pd.DataFrame:
    """The tabulated source ``name`` as a DataFrame (its ``columns`` and ``rows``)."""
    entry = paper_values(package)[name]
    return pd.DataFrame(entry["rows"], columns=entry["columns"])


def paper_label(package: str, name: str) -> str:
    """``"{paper} {source}"`` of entry ``name``, e.g. ``"Liu et al. 2023 Table 2"``."""
    values = paper_values(package)
    return f"{values['paper']} {values[name]['source']}"
