"""Cost and accuracy of the batch smoother with transmitter power offsets on ``adsb-snr``.

For each pass length (default 5, 15, 30 and 60 min) of the ``adsb-snr`` scenario
with every aircraft's power off by ``N(0, 2 dB)`` (``traffic.power_offset_sigma_db``;
the pass of :func:`attopt.experiments.benchmarks.smoother.adsb_pass`: truncated SNR
model, ``mems`` gyro at 10 Hz), it runs, as the experiment does:

* ``fg_batch``, the smoother that ignores the offsets, from the MEKF + RTS pass
  (the reference of the same run; the RTS pass's time is its start's);
* ``fg_batch_offsets``, one offset per aircraft (prior 2 dB), from the single-frame
  NLP with the offsets' spread as its power allowance
  (:func:`attopt.experiments.adsb_snr.experiment.offsets_start`; the NLP's time, after
  one untimed epoch per padding size, is its start's);

and prints each smoother's time alone and with its start, split into set-up,
optimisation and marginals, its ratio to ``fg_batch`` of the same pass, the time per
doubling of the pass, the largest number of offsets active in the elimination
(aircraft between their first and last reception,
:mod:`attopt.solvers.smoother.offset_elimination`), and each one's valid fraction,
RMS error of the valid epochs, mean NEES and integrity share (valid epochs whose NEES is
beyond the chi-square(3) 1 - 1e-4 quantile).

Run with ``python -m attopt.experiments.benchmarks.offsets`` (``--durations 300 900``
for others; the hour's MEKF takes a few minutes).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from attopt.experiments.adsb_snr.experiment import (
    OFFSETS_START,
    snr_snapshots,
    timed_pass,
)
from attopt.experiments.benchmarks.smoother import adsb_pass
from attopt.experiments.metrics import in_inertial_frame
from attopt.experiments.reporting.statistics import nees_threshold
from attopt.formulations.conventions import attitude_error
from attopt.solvers.registry import estimator
from attopt.solvers.results import Track
from attopt.solvers.smoother import single_frame_initial
from attopt.solvers.smoother.offset_elimination import active_counts

OFFSET_SIGMA_DB = 2.0


@dataclass(frozen=True)
class Smoothed:
    """One smoother's run: its time alone and its start's, the report's split, and the
    accuracy of its valid epochs."""

    seconds: float
    start_s: float
    split: dict[str, float]
    iterations: int
    converged: bool
    valid: float
    rms_deg: float
    nees: float
    beyond: float
    """Share of the valid epochs whose NEES is beyond the chi-square(3) 1 - 1e-4 quantile."""


@dataclass(frozen=True)
class Row:
    duration_s: float
    snrs: int
    aircraft: int
    active: int
    plain: Smoothed
    offsets: Smoothed


def _smoothed(track: Track, seconds: float, start_s: float, truth) -> Smoothed:
    report = track.report
    valid = track.valid
    error = attitude_error(track.attitude(), truth[valid]) if valid.any() else np.zeros((0, 3))
    nees = np.einsum("ki,kij,kj->k", error, np.linalg.inv(track.covariance[valid]), error)
    return Smoothed(
        seconds=seconds,
        start_s=start_s,
        split={k: report.seconds[k] for k in ("factors", "optimisation", "marginals")},
        iterations=report.iterations,
        converged=report.converged,
        valid=float(valid.mean()),
        rms_deg=float(np.degrees(np.sqrt(np.mean(np.sum(error**2, axis=1)))))
        if valid.any()
        else np.nan,
        nees=float(nees.mean()) if valid.any() else np.nan,
        beyond=float(np.mean(nees > nees_threshold())) if valid.any() else np.nan,
    )


def run(duration_s: float, seed: int) -> Row:
    """One pass of ``duration_s`` (module docstring)."""
    benchmark = adsb_pass(duration_s, seed, "mems", OFFSET_SIGMA_DB)
    simulated = benchmark.simulated
    pass_, truth = simulated.pass_, simulated.attitude

    start = time.perf_counter()
    forward = estimator("mekf").solve(pass_)
    rts = estimator("rts").solve(pass_, initial=forward)
    rts_s = time.perf_counter() - start
    start = time.perf_counter()
    plain = estimator("fg_batch").solve(pass_, initial=rts)
    plain_s = time.perf_counter() - start

    nlp = estimator(OFFSETS_START, power_offset_sigma_db=OFFSET_SIGMA_DB)
    frames, nlp_s = timed_pass(nlp, snr_snapshots(benchmark.epochs))
    first = single_frame_initial(in_inertial_frame(frames, simulated.frames), pass_.prior)
    start = time.perf_counter()
    offsets = estimator("fg_batch_offsets", offset_sigma=OFFSET_SIGMA_DB).solve(
        pass_, initial=first
    )
    offsets_s = time.perf_counter() - start

    report = offsets.report
    problem = report.problem
    seen = [np.zeros(0, dtype=np.intp)] * problem.n
    for f in problem.factors:
        seen[f.node] = np.unique(f.offset_index[f.rows])
    return Row(
        duration_s=duration_s,
        snrs=int(sum(m.size for m in pass_.measurements() if m is not None)),
        aircraft=int(report.offset_ids.size),
        active=int(active_counts(seen, problem.n_offsets).max()),
        plain=_smoothed(plain, plain_s, rts_s, truth),
        offsets=_smoothed(offsets, offsets_s, nlp_s, truth),
    )


def format_table(rows: list[Row]) -> str:
    lines = [
        f"Batch smoother on adsb-snr with {OFFSET_SIGMA_DB:g} dB power offsets (truncated SNR "
        "model, mems gyro at 10 Hz); times in seconds, the start's in brackets.",
        "",
        "| pass | SNRs | aircraft | largest active set | fg_batch | fg_batch_offsets | "
        "factors / optimise / marginals | iterations | offsets / plain (with starts) | "
        "per doubling |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    previous = None
    for r in rows:
        doubling = ""
        with_starts = (r.offsets.seconds + r.offsets.start_s) / (r.plain.seconds + r.plain.start_s)
        if previous is not None:
            exponent = np.log2(r.duration_s / previous.duration_s)
            doubling = f"{(r.offsets.seconds / previous.offsets.seconds) ** (1.0 / exponent):.2f}"
        o, p = r.offsets, r.plain
        split = " / ".join(f"{o.split[k]:.1f}" for k in ("factors", "optimisation", "marginals"))
        lines.append(
            f"| {r.duration_s / 60:.0f} min | {r.snrs} | {r.aircraft} | {r.active} | "
            f"{p.seconds:.1f} ({p.start_s:.1f}) | {o.seconds:.1f} ({o.start_s:.1f}) | {split} | "
            f"{o.iterations}{'' if o.converged else ' (NOT converged)'} | "
            f"{o.seconds / p.seconds:.2f} ({with_starts:.2f}) | "
            f"{doubling} |"
        )
        previous = r
    lines += [
        "",
        "Valid fraction, RMS error of the valid epochs (deg), mean NEES and the share of the "
        "valid epochs beyond the chi-square(3) 1 - 1e-4 quantile:",
        "",
        "| pass | fg_batch | fg_batch_offsets |",
        "|---|---|---|",
    ]
    for r in rows:
        cells = " | ".join(
            f"{s.valid:.3f}, {s.rms_deg:.3f}, {s.nees:.2f}, {s.beyond:.2g}"
            for s in (r.plain, r.offsets)
        )
        lines.append(f"| {r.duration_s / 60:.0f} min | {cells} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--durations", type=float, nargs="+", default=[300.0, 900.0, 1800.0, 3600.0]
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = []
    for duration in sorted(args.durations):
        rows.append(run(duration, args.seed))
        r = rows[-1]
        print(
            f"{duration:.0f} s: fg_batch {r.plain.seconds:.1f} s, fg_batch_offsets "
            f"{r.offsets.seconds:.1f} s ({r.offsets.iterations} iterations)",
            flush=True,
        )
    print(format_table(rows))


if __name__ == "__main__":
    main()
