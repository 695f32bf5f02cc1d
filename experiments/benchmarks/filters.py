"""Benchmark of the filters on ``adsb-snr``: NEES consistency over many trials, and speed.

Runs ``trials`` Monte Carlo passes of the ``adsb-snr``
experiment with only the SNR filters (``mekf_snr``, ``usque_snr``,
``rts_snr``; no single-frame method) through the sweep runner, for each gyro
model, then reports per filter:

* the consistency test of Bar-Shalom, Li and Kirubarajan (2001, sec. 5.4):
  at each epoch the attitude NEES averaged over the ``M`` trials is
  ``chi2(3 M) / M`` distributed for a consistent filter.  Its time average
  over the epochs after ``burn_in_s`` is compared with the two-sided 95%
  interval of ``chi2(3 M) / M`` (the interval of one epoch: errors are
  correlated in time, so averaging over epochs does not shrink it by the
  number of epochs; this is the conservative choice), and the fraction of
  epochs whose run-averaged NEES lies inside that interval is given (95%
  expected);
* the same for the 6-state NEES (attitude and bias) with ``chi2(6 M) / M``;
* the RMS attitude error and the mean pass time, with the ratio of each
  filter's time to ``mekf_snr``'s measured in the same run.

Run with ``python -m attopt.experiments.benchmarks.filters`` (defaults: 100 trials of the
hour, both gyro models, all CPUs).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import chi2

from attopt.experiments.adsb_snr.experiment import EXPERIMENT
from attopt.experiments.sweep import run_sweep

FILTERS = ["mekf_snr", "usque_snr", "rts_snr"]
REFERENCE = "mekf_snr"
BURN_IN_S = 300.0


@dataclass(frozen=True)
class ConsistencyRow:
    gyro: str
    method: str
    trials: int
    nees: float
    nees_low: float
    nees_high: float
    inside_fraction: float
    nees_full: float
    full_low: float
    full_high: float
    rms_deg: float
    runtime_s: float
    runtime_ratio: float

    @property
    def consistent(self) -> bool:
        return self.nees_low <= self.nees <= self.nees_high


def consistency(rows: pd.DataFrame, burn_in_s: float = BURN_IN_S) -> list[ConsistencyRow]:
    """Per gyro and filter: the statistics of the module docstring."""
    out = []
    rows = rows[rows["t_s"] >= burn_in_s]
    for (gyro, method), group in rows.groupby(["gyro", "method"], sort=True):
        m = group["trial_index"].nunique()
        per_epoch = group.groupby("t_s")[["nees", "nees_full"]].mean()
        low, high = chi2.ppf([0.025, 0.975], 3 * m) / m
        full_low, full_high = chi2.ppf([0.025, 0.975], 6 * m) / m
        inside = per_epoch["nees"].between(low, high).mean()
        squared = sum(group[f"err_{a}_deg"] ** 2 for a in "xyz")
        runtime = group.groupby("trial_index")["runtime_s"].first().mean()
        out.append(
            ConsistencyRow(
                gyro=str(gyro),
                method=str(method),
                trials=m,
                nees=float(per_epoch["nees"].mean()),
                nees_low=float(low),
                nees_high=float(high),
                inside_fraction=float(inside),
                nees_full=float(per_epoch["nees_full"].mean()),
                full_low=float(full_low),
                full_high=float(full_high),
                rms_deg=float(np.sqrt(squared.mean())),
                runtime_s=float(runtime),
                runtime_ratio=np.nan,
            )
        )
    reference = {r.gyro: r.runtime_s for r in out if r.method == REFERENCE}
    return [
        ConsistencyRow(**{**r.__dict__, "runtime_ratio": r.runtime_s / reference[r.gyro]})
        if r.gyro in reference
        else r
        for r in out
    ]


def format_table(results: list[ConsistencyRow], duration_s: float) -> str:
    lines = [
        f"Filters on adsb-snr, {duration_s:.0f} s passes, epochs after {BURN_IN_S:.0f} s; "
        "NEES: time average of the run-averaged NEES; interval: two-sided 95% of chi2(nM)/M.",
        "",
        "| gyro | filter | trials | NEES (3) | 95% interval | inside | epochs inside | "
        "NEES (6) | 95% interval | RMS (deg) | pass (s) | time / mekf_snr |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.gyro} | {r.method} | {r.trials} | {r.nees:.3f} | "
            f"[{r.nees_low:.3f}, {r.nees_high:.3f}] | {'yes' if r.consistent else 'NO'} | "
            f"{r.inside_fraction:.3f} | {r.nees_full:.3f} | "
            f"[{r.full_low:.3f}, {r.full_high:.3f}] | {r.rms_deg:.4f} | {r.runtime_s:.2f} | "
            f"{r.runtime_ratio:.2f} |"
        )
    return "\n".join(lines)


def run(
    trials: int, duration_s: float, gyros: list[str], workers: int | None, out: Path
) -> list[ConsistencyRow]:
    overrides = {"duration_s": duration_s, "methods": [], "filters": FILTERS, "gyros": gyros}
    sweep = run_sweep(
        EXPERIMENT, trials=trials, out=out, workers=workers, overrides=overrides, fresh=True
    )
    return consistency(sweep.rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--duration", type=float, default=3600.0, help="pass length (s)")
    parser.add_argument("--gyro", action="append", help="gyro model (repeatable)")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None, help="keep the rows here")
    args = parser.parse_args()
    gyros = args.gyro or ["liu2023", "mems"]
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or Path(scratch) / "bench_filters"
        results = run(args.trials, args.duration, gyros, args.workers, out)
    print(format_table(results, args.duration))


if __name__ == "__main__":
    main()
