"""Overhead of the sweep engines against a plain serial loop of the same trials.

Two trial kinds of the ``noop`` experiment: one that only draws random
numbers, and one that sleeps (0.5 s by default) like a real solver would
compute.  Each is run as a plain ``for`` loop calling the trial function (the
reference), then through :func:`~attopt.experiments.sweep.run_sweep` with the local
engine on 1 worker (in process) and on N workers (process pool), and with a
Dask LocalCluster of N workers.  Wall times include everything a user waits
for: starting the workers, storing chunks, aggregating and writing the report.

The overhead per trial is the worker time spent beyond the serial loop,
``(workers * wall - serial) / trials``; with perfect scaling it is zero.  Most
of it is the fixed cost of starting the workers, measured separately as the
wall time of a sweep of one no-op trial per setting (fastest of three runs,
"startup"); the overhead after startup subtracts it:
``(workers * (wall - startup) - serial) / trials``.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from attopt.experiments.sweep import resolve_parameters, run_sweep, trial_seed
from attopt.experiments.sweep.toys import NOOP

SETTINGS = 4
SEED = 0
NOOP_LABEL = "no-op"
SERIAL_LABEL = "serial loop"


@dataclass(frozen=True)
class BenchRow:
    """Timing of one engine on one trial kind, with the serial loop of that kind."""

    trial: str
    engine: str
    workers: int
    trials: int
    wall_s: float
    serial_s: float
    startup_s: float

    @property
    def per_trial_ms(self) -> float:
        """Wall time per trial."""
        return 1e3 * self.wall_s / self.trials

    @property
    def overhead_ms(self) -> float:
        """Worker time per trial beyond the serial loop's."""
        return 1e3 * (self.workers * self.wall_s - self.serial_s) / self.trials

    @property
    def steady_overhead_ms(self) -> float:
        """Worker time per trial beyond the serial loop's, once the workers are started."""
        busy = self.workers * (self.wall_s - self.startup_s)
        return 1e3 * (busy - self.serial_s) / self.trials

    @property
    def ratio(self) -> float:
        """Wall time relative to the serial loop."""
        return self.wall_s / self.serial_s


def run_benchmark(
    *, noop_trials: int = 2000, sleep_trials: int = 24, sleep_s: float = 0.5, workers: int = 2
) -> list[BenchRow]:
    """Time the serial loop and every engine on the no-op and the sleep trials."""
    engines = (("local", 1), ("local", workers), ("dask", workers))
    idle = {"settings": SETTINGS, "sleep_s": 0.0}
    startup = {
        engine: min(timed_sweep(*engine, idle, trials=1) for _ in range(3)) for engine in engines
    }
    rows = []
    for label, seconds, total in (
        (NOOP_LABEL, 0.0, noop_trials),
        (f"sleep {sleep_s:g} s", sleep_s, sleep_trials),
    ):
        overrides = {"settings": SETTINGS, "sleep_s": seconds}
        trials = total // SETTINGS
        serial = serial_loop(overrides, trials)
        rows.append(BenchRow(label, SERIAL_LABEL, 1, trials * SETTINGS, serial, serial, 0.0))
        for engine, count in engines:
            wall = timed_sweep(engine, count, overrides, trials)
            name = "dask LocalCluster" if engine == "dask" else engine
            rows.append(
                BenchRow(
                    label, name, count, trials * SETTINGS, wall, serial, startup[engine, count]
                )
            )
    return rows


def serial_loop(overrides: dict[str, float], trials: int) -> float:
    """Return the time of a plain loop calling the trial function for every setting x trial."""
    settings = NOOP.grid(resolve_parameters(NOOP, overrides=overrides).model_dump(mode="json"))
    started = time.perf_counter()
    for trial_index in range(trials):
        for setting_index, setting in enumerate(settings):
            NOOP.trial(dict(setting), trial_seed(SEED, setting_index, trial_index))
    return time.perf_counter() - started


def timed_sweep(engine: str, workers: int, overrides: dict[str, float], trials: int) -> float:
    """Return the wall time of a complete sweep into a fresh temporary directory."""
    with tempfile.TemporaryDirectory(prefix="attopt-bench-") as out:
        started = time.perf_counter()
        result = run_sweep(
            NOOP,
            trials=trials,
            engine=engine,
            workers=workers,
            seed=SEED,
            out=Path(out),
            progress=False,
            overrides=overrides,
        )
        wall = time.perf_counter() - started
    if not result.complete or result.n_failed:
        raise RuntimeError(f"benchmark sweep on {engine} did not complete: {result.errors}")
    return wall


def format_table(rows: list[BenchRow]) -> str:
    """Return the timings as markdown: all runs, then fixed and marginal costs per engine.

    The marginal cost after startup is shown for the no-op trial only: with
    slow trials it is lost in the run-to-run noise of the startup time.
    """
    lines = [
        "| trial | engine | workers | trials | wall s | wall / serial loop | per trial ms "
        "| overhead per trial ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row.trial} | {row.engine} | {row.workers} | {row.trials} | {row.wall_s:.2f} "
            f"| {row.ratio:.3g} | {row.per_trial_ms:.3g} | {row.overhead_ms:.3g} |"
        )
    lines += [
        "",
        "| engine | workers | startup s | no-op overhead per trial after startup ms |",
        "|---|---|---|---|",
    ]
    for row in rows:
        if row.trial == NOOP_LABEL and row.engine != SERIAL_LABEL:
            lines.append(
                f"| {row.engine} | {row.workers} | {row.startup_s:.2f} "
                f"| {row.steady_overhead_ms:.3g} |"
            )
    return "\n".join(lines)
