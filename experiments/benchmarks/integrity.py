"""The mismatch cases, and what honesty costs: each estimator with its integrity tests
on and off.

Each case is a departure of the simulated world from the estimators' model, set by the
experiment's own parameters (so it also runs as ``attopt run EXPERIMENT --config
FILE``; ``--print-config CASE`` prints the file).  Every case runs twice through the
sweep runner, with the same seeds:

* **tests on**: the estimators as configured;
* **tests off**: every estimator with its integrity tests turned off
  (:func:`attopt.solvers.registry.integrity_tests_off`: the filters' windowed
  innovation test, the snapshot estimators' residual test and the batch smoother's
  whole-pass variance factor), so an epoch is flagged
  only by its solver's own checks (convergence, gating, a lost track, a covariance too
  wide to mean anything).

Per case and group (the setting columns that vary, then the experiment's ``group_by``,
as ``attopt check`` groups them) it reports, off -> on: the valid fraction, the total
RMS error of the valid epochs, and the share of valid epochs whose NEES exceeds the
chi-square 1 - 1e-4 quantile (:func:`attopt.experiments.reporting.statistics.integrity`).
The tests' cost is the valid epochs they take away and the change of the RMS; their
gain is the share they bring down.

Run with ``python -m attopt.experiments.benchmarks.integrity`` (all cases), ``--case
NAME`` (repeatable), ``--trials N`` to override the cases' trial counts, ``--out DIR`` to
keep the rows.
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import tomli_w

from attopt.experiments.config.loading import deep_merge
from attopt.experiments.registry import get_experiment
from attopt.experiments.reporting.statistics import integrity, total_rms, valid_mask
from attopt.experiments.sweep import run_sweep
from attopt.experiments.sweep.check import results_rows
from attopt.solvers.registry import ESTIMATORS, integrity_tests_off

SHORT_ADSB_PASS = {"duration_s": 300.0}
"""Five minutes of ``adsb-snr``: long enough for the filters to settle and a fault to pass."""
SUNLIT_WAHBA_PASS = {"duration_s": 1000.0}
"""The first 1000 s of ``wahba-mag-sun``, in sunlight (the eclipse begins at 1001 s)."""
STUCK_Y = {"axis": "y", "start_s": 600.0, "duration_s": 60.0}
"""The gyro's y axis stuck for a minute, after the filters have settled."""


@dataclass(frozen=True)
class MismatchCase:
    """One departure of the world from the model.

    Attributes:
        name: the case's label.
        experiment: the registered experiment it runs.
        parameters: the parameters it sets, over the experiment's quick values.
        trials: Monte Carlo trials.
        what: one sentence on what departs from the model.
    """

    name: str
    experiment: str
    parameters: dict[str, Any] = field(default_factory=dict)
    trials: int = 2
    what: str = ""


CASES = (
    MismatchCase(
        "power-offsets",
        "adsb-snr",
        {**SHORT_ADSB_PASS, "traffic": {"power_offset_sigma_db": 2.0}},
        what="each aircraft's transmit power off the nominal by N(0, 2 dB), not modelled",
    ),
    MismatchCase(
        "outlier-burst",
        "adsb-snr",
        {
            **SHORT_ADSB_PASS,
            "receiver": {"outliers": {"start_s": 100.0, "duration_s": 30.0, "offset_db": 20.0}},
        },
        what="every SNR measured from 100 s to 130 s is 20 dB off",
    ),
    MismatchCase(
        "spoofed-position",
        "adsb-snr",
        {**SHORT_ADSB_PASS, "traffic": {"spoofer": {"aircraft": 1, "offset_km": 50.0}}},
        what="one aircraft broadcasts a position 50 km off its own",
    ),
    MismatchCase(
        "spoofed-position-far",
        "adsb-snr",
        {**SHORT_ADSB_PASS, "traffic": {"spoofer": {"aircraft": 1, "offset_km": 2000.0}}},
        what="one aircraft broadcasts a position 2000 km off its own",
    ),
    MismatchCase(
        "scale-factor",
        "wahba-mag-sun",
        {**SUNLIT_WAHBA_PASS, "gyro_fault": {"scale_factor": {"error": 0.01}}},
        trials=1,
        what="the gyro's scale factor 1 % off on every axis",
    ),
    MismatchCase(
        "time-offset",
        "wahba-mag-sun",
        {**SUNLIT_WAHBA_PASS, "gyro_fault": {"time_offset": {"offset_s": 0.5}}},
        trials=1,
        what="the gyro's time tags 0.5 s late against the measurements",
    ),
    MismatchCase(
        "stuck-axis",
        "wahba-mag-sun",
        {**SUNLIT_WAHBA_PASS, "gyro_fault": {"stuck_axis": STUCK_Y}},
        trials=1,
        what="the gyro's y axis frozen at its reading for 60 s from 600 s",
    ),
    MismatchCase(
        "dead-axis",
        "wahba-mag-sun",
        {**SUNLIT_WAHBA_PASS, "gyro_fault": {"stuck_axis": {**STUCK_Y, "value_deg_s": 0.0}}},
        trials=1,
        what="the gyro's y axis reading 0 for 60 s from 600 s",
    ),
    MismatchCase(
        "dead-axis-snr",
        "adsb-snr",
        {
            **SHORT_ADSB_PASS,
            "gyro_fault": {"stuck_axis": {**STUCK_Y, "start_s": 100.0, "value_deg_s": 0.0}},
        },
        what="the gyro's y axis reading 0 for 60 s from 100 s",
    ),
    MismatchCase(
        "doa-weak-signal",
        "doa-ground",
        {"table1_snr_db": [-14.0], "table2_snapshots": [1]},
        what="Yang et al. 2014's EKF from the 98 deg start at -14 dB with L = 100 snapshots "
        "and at 0 dB with L = 1",
    ),
    MismatchCase(
        "literal-gyro-eclipse",
        "wahba-mag-sun",
        {"gyro": "liu2023"},
        trials=1,
        what="the gyro of Liu et al. 2023 read literally (0.05 deg/s^(1/2) noise) "
        "through the eclipse",
    ),
)
"""The mismatch cases, by name (:func:`case`)."""


def case(name: str) -> MismatchCase:
    """The case called ``name``.

    Raises:
        KeyError: no such case (the message lists them).
    """
    found = {c.name: c for c in CASES}
    if name not in found:
        raise KeyError(f"unknown case {name!r}; cases: {', '.join(found)}")
    return found[name]


def options_without_tests() -> dict[str, Any]:
    """``estimator_options`` turning off every registered estimator's integrity tests."""
    tables = {name: integrity_tests_off(found) for name, found in ESTIMATORS.items()}
    return {"estimator_options": {name: table for name, table in tables.items() if table}}


def run_case(mismatch: MismatchCase, out: Path, trials: int | None = None) -> pd.DataFrame:
    """Run ``mismatch`` with the tests on and off into ``out/on`` and ``out/off``; the
    statistics of the module docstring per group, off and on side by side."""
    experiment = get_experiment(mismatch.experiment)
    sides = {}
    for side, overrides in (
        ("off", deep_merge(mismatch.parameters, options_without_tests())),
        ("on", mismatch.parameters),
    ):
        run_sweep(
            experiment,
            trials=trials or mismatch.trials,
            out=out / side,
            quick=True,
            overrides=overrides,
            progress=False,
            fresh=True,
        )
        rows, by = results_rows(out / side)
        sides[side] = group_statistics(rows, by)
    table = side_by_side(sides["off"], sides["on"])
    return table.reset_index().assign(case=mismatch.name)


def side_by_side(off: pd.DataFrame, on: pd.DataFrame) -> pd.DataFrame:
    """The statistics of :func:`group_statistics` with the tests off and on, columns
    ``"{statistic} off"`` and ``"{statistic} on"``, per group."""
    return off.merge(on, how="outer", left_index=True, right_index=True, suffixes=(" off", " on"))


def group_statistics(rows: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Per group of ``by``: ``valid``, ``RMS (deg)`` of the valid epochs and ``share``
    beyond the quantile, indexed by the group's label (``"key=value, ..."``)."""
    stats = integrity(rows, by)
    valid = rows[valid_mask(rows)]
    rms = valid.groupby(by, sort=False, dropna=False).apply(total_rms, include_groups=False)
    frame = pd.DataFrame(
        {
            "valid": stats["valid_fraction"],
            "RMS (deg)": rms.reindex(stats.index),
            "share": stats["share_beyond"],
        }
    )
    frame.index = [label(by, key) for key in frame.index]
    frame.index.name = "group"
    return frame


def label(by: list[str], key: Any) -> str:
    """``"value, key=value, ..."``: the group's method first, its settings after."""
    values = dict(zip(by, key if isinstance(key, tuple) else (key,), strict=True))
    method = values.pop("method", None)
    settings = ", ".join(f"{k}={v}" for k, v in values.items())
    return ", ".join(str(part) for part in (method, settings) if part)


COLUMNS = {"valid": ".3f", "RMS (deg)": ".3g", "share": ".3g"}
"""The statistics of a group and their formats."""


def format_table(table: pd.DataFrame) -> str:
    """The markdown table of :func:`run_case`'s results, one row per case and group, each
    statistic as ``off -> on``."""
    header = ["case", "estimator", *(f"{c} off -> on" for c in COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for _, row in table.iterrows():
        cells = [str(row["case"]), str(row["group"])]
        for column, spec in COLUMNS.items():
            off, on = (_number(row[f"{column} {side}"], spec) for side in ("off", "on"))
            cells.append(f"{off} -> {on}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _number(value: float, spec: str) -> str:
    return "n/a" if not np.isfinite(value) else format(value, spec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", action="append", help="case name (repeatable; default all)")
    parser.add_argument("--trials", type=int, default=None, help="trials of every case")
    parser.add_argument("--out", type=Path, default=None, help="keep the rows here")
    parser.add_argument("--print-config", metavar="CASE", help="print a case's config and stop")
    args = parser.parse_args()
    if args.print_config:
        mismatch = case(args.print_config)
        print(f"# attopt run {mismatch.experiment} --quick --config {mismatch.name}.toml")
        print(f"# {mismatch.what}")
        print(tomli_w.dumps(mismatch.parameters), end="")
        return
    chosen = [case(name) for name in args.case] if args.case else list(CASES)
    with tempfile.TemporaryDirectory() as scratch:
        root = args.out or Path(scratch)
        tables = [run_case(c, root / c.name, args.trials) for c in chosen]
    print(format_table(pd.concat(tables, ignore_index=True)))


if __name__ == "__main__":
    main()
