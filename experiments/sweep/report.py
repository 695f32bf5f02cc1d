"""The generic part of ``report.md``: what was run, the summary, the failures and, for an
experiment without its own report, the integrity section."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pandas as pd

from attopt.experiments.config.schema import flat_items
from attopt.experiments.reporting.tables import markdown_table

MAX_FAILURE_KINDS = 10


@dataclass(frozen=True)
class RunDescription:
    """What the report says about the sweep besides its results."""

    name: str
    summary: str
    command: str
    parameters: Mapping[str, Any]
    n_settings: int
    trials: int
    seed: int
    n_finished: int
    n_failed: int
    n_missing: int
    code_versions: Mapping[str, int]
    """Finished trials per version of the code that computed them."""


def render_report(
    run: RunDescription,
    summary: pd.DataFrame,
    reasons: pd.DataFrame,
    failures: pd.DataFrame,
    integrity: str = "",
) -> str:
    """Return the markdown of the generic report (``integrity``: the integrity section of
    :mod:`attopt.experiments.reporting.integrity`, if any)."""
    flat = flat_items(run.parameters)
    parameters = pd.DataFrame({"parameter": list(flat), "value": [repr(v) for v in flat.values()]})
    parts = [
        f"# {run.name}\n\n{run.summary}\n",
        "## Reproduce\n\n"
        f"```\n{run.command}\n```\n\n"
        "Results depend only on the experiment, its parameters, the seed and the "
        "number of trials, not on the engine or the number of workers.\n",
        "## Parameters\n\n" + markdown_table(parameters),
        "## Trials\n\n" + _trial_counts(run),
        "## Results\n\n" + (markdown_table(summary) if len(summary) else "No rows.\n"),
    ]
    if len(reasons):
        parts.append("## Invalid rows (most common reasons)\n\n" + markdown_table(reasons))
    if integrity:
        parts.append(integrity)
    parts.append("## Failed trials\n\n" + _failures_section(failures))
    return "\n".join(parts)


def _trial_counts(run: RunDescription) -> str:
    total = run.n_settings * run.trials
    lines = [
        f"- {run.n_settings} settings x {run.trials} trials = {total} trials, seed {run.seed}",
        f"- finished: {run.n_finished} (of which failed: {run.n_failed})",
    ]
    if run.n_missing:
        lines.append(
            f"- **missing: {run.n_missing}** (not finished; rerun the command to complete them)"
        )
    versions = ", ".join(f"`{code}` ({n} trials)" for code, n in run.code_versions.items())
    lines.append(f"- computed by code version{'s' * (len(run.code_versions) > 1)}: {versions}")
    return "\n".join(lines) + "\n"


def _failures_section(failures: pd.DataFrame) -> str:
    if not len(failures):
        return "None.\n"
    kinds = (
        failures.groupby(["error_type", "message"], sort=False)
        .agg(trials=("trial_index", "size"), first_seed=("seed", "first"))
        .reset_index()
        .sort_values("trials", ascending=False, kind="stable")
    )
    text = (
        f"{len(failures)} trials raised an exception; they are listed with their "
        "tracebacks in `failures.csv`.\n\n" + markdown_table(kinds.head(MAX_FAILURE_KINDS))
    )
    if len(kinds) > MAX_FAILURE_KINDS:
        text += f"\n({len(kinds) - MAX_FAILURE_KINDS} more kinds of failure in failures.csv)\n"
    return text


def failure_digest(failures: pd.DataFrame, limit: int = 3) -> Sequence[str]:
    """Return one line per most common failure kind, e.g. ``"4 x ValueError: bad input"``."""
    if not len(failures):
        return []
    counts = failures.groupby(["error_type", "message"], sort=False).size()
    counts = counts.sort_values(ascending=False, kind="stable").head(limit)
    return [f"{n} x {error_type}: {message}" for (error_type, message), n in counts.items()]
