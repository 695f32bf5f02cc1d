"""The ``attopt`` command line: run and list experiments, list estimators, run benchmarks.

Heavy modules (pandas, the sweep runner, Dask) are imported inside the
commands so that ``attopt --help`` and ``attopt list`` start quickly.
"""

from __future__ import annotations

import os
import sys
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    import pandas as pd

    from attopt.experiments.experiment import Experiment
    from attopt.experiments.sweep import SweepResult

app = typer.Typer(
    help="Spacecraft attitude determination as optimisation, compared by Monte Carlo.",
    no_args_is_help=True,
)
bench_app = typer.Typer(help="Benchmarks of the runner and of the solvers.", no_args_is_help=True)
app.add_typer(bench_app, name="bench")

SUMMARY_COLUMNS = (
    "n_valid",
    "n_rows",
    "roll_rms_deg",
    "pitch_rms_deg",
    "yaw_rms_deg",
    "total_rms_deg",
    "p95_deg",
    "roll_ratio",
    "pitch_ratio",
    "yaw_ratio",
    "failed_trials",
)
MAX_ERRORS_SHOWN = 5
EXIT_USAGE = 2
EXIT_INCOMPLETE = 1
EXIT_INTEGRITY = 1
"""``attopt check --max-share``: some group's share beyond the quantile exceeds it."""
EXIT_INTERRUPTED = 130


class EngineName(StrEnum):
    """Where the trials run."""

    local = "local"
    dask = "dask"


@app.command()
def run(
    experiment: Annotated[
        str, typer.Argument(help="Registered name (see `attopt list`) or 'module:OBJECT'.")
    ],
    trials: Annotated[
        int | None,
        typer.Option(min=1, help="Trials per setting (default: the experiment's)."),
    ] = None,
    engine: Annotated[EngineName, typer.Option(help="Process pool here, or Dask.")] = (
        EngineName.local
    ),
    address: Annotated[
        str | None,
        typer.Option(help="Dask scheduler, e.g. tcp://HOST:8786 (default: start a LocalCluster)."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(
            min=1, help="Worker processes of the pool or LocalCluster (default: one per CPU)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(min=0, help="Root seed of the sweep.")] = 0,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Output directory (default: results/NAME[-CONFIG][-quick], CONFIG the "
            "config file's name without .toml)."
        ),
    ] = None,
    quick: Annotated[bool, typer.Option(help="Small version: quick parameters and trials.")] = (
        False
    ),
    config: Annotated[
        Path | None, typer.Option(help="TOML file whose parameters table overrides parameters.")
    ] = None,
    fresh: Annotated[
        bool, typer.Option(help="Discard results already in --out instead of resuming.")
    ] = False,
    chunk_size: Annotated[
        int | None, typer.Option(min=1, help="Trials per stored chunk (default: automatic).")
    ] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar with ETA.")] = True,
) -> None:
    """Run a Monte Carlo sweep of EXPERIMENT, resuming what is already in --out."""
    from attopt.experiments.sweep import (
        ConfigError,
        EngineSetupError,
        ManifestMismatchError,
        run_sweep,
    )

    declared = _load_experiment(experiment)
    out = out or default_out(declared.name, config, quick)
    try:
        result = run_sweep(
            declared,
            trials=trials,
            engine=engine.value,
            address=address,
            workers=workers,
            seed=seed,
            out=out,
            quick=quick,
            config=config,
            progress=progress,
            fresh=fresh,
            chunk_size=chunk_size,
        )
    except ConfigError as error:
        for problem in error.problems:
            typer.echo(f"error: {error.source}: {problem}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    except (EngineSetupError, ManifestMismatchError) as error:
        typer.echo(f"error: {error}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    except KeyboardInterrupt:
        typer.echo(
            f"\ninterrupted: finished chunks are kept in {out}; rerun the same command to resume",
            err=True,
        )
        raise typer.Exit(EXIT_INTERRUPTED) from None
    _print_result(result, declared)
    if not result.complete:
        raise typer.Exit(EXIT_INCOMPLETE)


def default_out(name: str, config: Path | None, quick: bool) -> Path:
    """``results/NAME[-CONFIG][-quick]``: variants of one experiment do not collide."""
    parts = [name, *([config.stem] if config is not None else []), *(["quick"] if quick else [])]
    return Path("results") / "-".join(parts)


@app.command()
def show(
    experiment: Annotated[
        str, typer.Argument(help="Registered name (see `attopt list`) or 'module:OBJECT'.")
    ],
    toml: Annotated[
        bool, typer.Option("--toml", help="Print a complete starter config instead.")
    ] = False,
    quick: Annotated[bool, typer.Option(help="With the quick variant's values.")] = False,
) -> None:
    """Print every parameter of EXPERIMENT with its default, unit and meaning."""
    from attopt.experiments.config import describe, resolve_parameters, starter_toml

    declared = _load_experiment(experiment)
    parameters = resolve_parameters(declared, quick=quick)
    if toml:
        header = (
            f"attopt run {declared.name} --config THIS_FILE\n{declared.summary.splitlines()[0]}"
        )
        typer.echo(starter_toml(parameters, header), nl=False)
        return
    leaves = describe(declared.schema, parameters)
    rows = [(leaf.path, _shown(leaf.default), leaf.unit) for leaf in leaves]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    for row, leaf in zip(rows, leaves, strict=True):
        cells = "  ".join(f"{cell:<{w}}" for cell, w in zip(row, widths, strict=True))
        typer.echo(f"{cells}  {leaf.description}")


def _shown(value: object) -> str:
    text = "-" if value is None else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _load_experiment(name: str) -> Experiment:
    """The experiment called ``name``; exit 2 with a one-line message if there is none."""
    from attopt.experiments.registry import UnknownExperimentError, get_experiment

    if ":" in name and os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())  # like `python -m`; spawned workers inherit sys.path
    try:
        return get_experiment(name)
    except (UnknownExperimentError, ImportError) as error:
        typer.echo(f"error: cannot load experiment {name!r}: {error}", err=True)
        raise typer.Exit(EXIT_USAGE) from None


@app.command()
def check(
    out: Annotated[Path, typer.Argument(help="A results directory (attopt run or estimate).")],
    max_share: Annotated[
        float | None,
        typer.Option(help="Exit 1 when some group's share beyond the quantile exceeds this."),
    ] = None,
) -> None:
    """Print the integrity of the estimates in OUT: per group, the share of valid epochs
    whose NEES exceeds the chi-square 1 - 1e-4 quantile, the mean NEES, the valid share,
    and the share of epochs flagged for each kind of reason."""
    from attopt.experiments.reporting.integrity import flagged_table, integrity_table
    from attopt.experiments.sweep.check import ResultsError, results_rows

    try:
        rows, by = results_rows(out)
    except ResultsError as error:
        typer.echo(f"error: {error}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    typer.echo(integrity_table(rows, by).to_string(index=False, float_format="{:.4g}".format))
    typer.echo("\nShare of the epochs flagged, by kind of reason:")
    typer.echo(flagged_table(rows, by).to_string(index=False, float_format="{:.3g}".format))
    share = _echo_worst_share(rows, by)
    if max_share is not None and share > max_share:
        raise typer.Exit(EXIT_INTEGRITY)


def _echo_worst_share(rows: pd.DataFrame, by: list[str]) -> float:
    """Print the worst group's share beyond the quantile; return it (no NEES: 0)."""
    from attopt.experiments.reporting.integrity import worst_share

    share, group = worst_share(rows, by)
    if group and share == 0.0:
        typer.echo("Integrity: no valid epoch beyond the chi-square 1 - 1e-4 quantile in any group")
        return share
    if group:
        typer.echo(
            f"Integrity: worst share of valid epochs beyond the chi-square 1 - 1e-4 quantile "
            f"{share:.3g} ({group}); 1e-4 for a consistent estimator"
        )
        return share
    typer.echo("Integrity: no NEES in the rows (no estimate with a covariance and a truth)")
    return 0.0


@app.command("list")
def list_command() -> None:
    """List the registered experiments."""
    from attopt.experiments.registry import list_experiments

    listing = list_experiments()
    width = max((len(name) for name, _ in listing), default=0)
    for name, summary in listing:
        typer.echo(f"{name:<{width}}  {summary}")


@app.command("compile")
def compile_command(
    loops: Annotated[
        list[str] | None,
        typer.Argument(
            help="Loop names or their prefixes, e.g. wahba filters.gate (default: all)."
        ),
    ] = None,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Processes compiling (default: one per CPU).")
    ] = None,
) -> None:
    """Compile attopt's numba loops once for this machine, each loop in one process.

    A sweep does this for the loops its experiment uses before its first trial; this
    command does it ahead, for example when building an image.  Loops already compiled
    are loaded from numba's cache in a fraction of a second.
    """
    import multiprocessing
    import time
    from concurrent.futures import ProcessPoolExecutor

    from attopt.solvers.compilation import compile_loops, loop_names

    try:
        names = loop_names(loops or [""])
    except KeyError as error:
        typer.echo(f"error: {error.args[0]}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    count = min(workers or os.cpu_count() or 1, len(names))
    start = time.perf_counter()
    if count == 1:
        seconds = compile_loops(names)
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=count, mp_context=context) as pool:
            seconds = compile_loops(names, pool)
    width = max(len(name) for name in names)
    for name, value in seconds.items():
        typer.echo(f"{name:<{width}}  {value:6.2f} s")
    processes = "process" if count == 1 else "processes"
    seconds_all = time.perf_counter() - start
    loops_ready = f"{len(names)} loop{'' if len(names) == 1 else 's'} ready"
    typer.echo(f"{loops_ready} in {seconds_all:.1f} s on {count} {processes}")


class EstimatorKind(StrEnum):
    """Which estimators to list."""

    snapshot = "snapshot"
    pass_ = "pass"


@app.command("estimators")
def estimators_command(
    kind: Annotated[
        EstimatorKind | None, typer.Option(help="Only snapshot or only pass estimators.")
    ] = None,
) -> None:
    """List the registered estimators: name, kind, accepted measurements, method."""
    from attopt.solvers.registry import ESTIMATORS

    rows = [
        (name, e.kind, ", ".join(a.__name__ for a in e.accepts), e.description)
        for name, e in ESTIMATORS.items()
        if kind is None or e.kind == kind.value
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    for row in rows:
        typer.echo(
            "  ".join(f"{cell:<{w}}" for cell, w in zip(row, widths, strict=False)) + "  " + row[3]
        )


@app.command()
def estimate(
    pass_dir: Annotated[Path, typer.Argument(help="A recorded pass (docs/pass-format.md).")],
    methods: Annotated[
        str, typer.Option(help="Registered estimators, comma separated (`attopt estimators`).")
    ],
    out: Annotated[
        Path | None, typer.Option(help="Output directory (default: results/estimate-PASS).")
    ] = None,
) -> None:
    """Run registered estimators on a recorded pass: rows, summary, report and figures."""
    from attopt.experiments.recorded.estimate import main

    raise typer.Exit(main(pass_dir, methods, out))


@app.command("export")
def export_command(
    experiment: Annotated[
        str, typer.Argument(help="Registered name (see `attopt list`) or 'module:OBJECT'.")
    ],
    out: Annotated[Path, typer.Argument(help="Directory of the recorded pass to write.")],
    setting: Annotated[int, typer.Option(min=0, help="Index of the setting in the grid.")] = 0,
    trial: Annotated[int, typer.Option(min=0, help="Trial index.")] = 0,
    seed: Annotated[int, typer.Option(min=0, help="Root seed of the sweep.")] = 0,
    quick: Annotated[bool, typer.Option(help="With the quick parameters.")] = False,
    config: Annotated[
        Path | None, typer.Option(help="TOML file of parameters (as for `attopt run`).")
    ] = None,
    csv: Annotated[bool, typer.Option("--csv", help="CSV tables instead of parquet.")] = False,
) -> None:
    """Write trial TRIAL of setting SETTING of EXPERIMENT as a recorded pass
    (docs/pass-format.md): the pass `attopt run` simulates for that trial, which
    `attopt estimate` reads back."""
    from attopt.experiments.config import ConfigError, resolve_parameters
    from attopt.experiments.recorded import save_pass
    from attopt.experiments.recorded.export import exporter
    from attopt.experiments.sweep.seeding import trial_seed

    declared = _load_experiment(experiment)
    try:
        export = exporter(experiment)
        document = resolve_parameters(declared, quick=quick, config=config).model_dump(mode="json")
    except ConfigError as error:
        for problem in error.problems:
            typer.echo(f"error: {error.source}: {problem}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    except ValueError as error:
        typer.echo(f"error: {error}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    settings = declared.grid(document)
    if setting >= len(settings):
        typer.echo(f"error: --setting {setting}: the grid has {len(settings)} settings", err=True)
        raise typer.Exit(EXIT_USAGE)
    recorded = export(settings[setting], trial_seed(seed, setting, trial))
    written = save_pass(recorded, out, "csv" if csv else "parquet")
    typer.echo(f"Recorded pass in {written}/ (`attopt estimate {written} --methods ...`)")


@bench_app.command("runner")
def bench_runner(
    noop_trials: Annotated[int, typer.Option(min=4, help="Trials of the no-op case.")] = 2000,
    sleep_trials: Annotated[int, typer.Option(min=4, help="Trials of the sleep case.")] = 24,
    sleep: Annotated[float, typer.Option(min=0.0, help="Seconds each sleep trial takes.")] = 0.5,
    workers: Annotated[int, typer.Option(min=2, help="Workers of the parallel engines.")] = 2,
) -> None:
    """Overhead per trial of each engine against a serial loop of the same trials."""
    from attopt.experiments.benchmarks.runner import format_table, run_benchmark

    rows = run_benchmark(
        noop_trials=noop_trials, sleep_trials=sleep_trials, sleep_s=sleep, workers=workers
    )
    typer.echo(format_table(rows))


@bench_app.command("wahba")
def bench_wahba(
    epochs: Annotated[int, typer.Option(min=1000, help="Epochs of the batched runs.")] = 100_000,
    calls: Annotated[int, typer.Option(min=100, help="Single-epoch calls per timing.")] = 2000,
) -> None:
    """Wahba solvers against scipy's align_vectors: per call and batched throughput."""
    from attopt.experiments.benchmarks.wahba import format_table, run

    typer.echo(format_table(run(n_batch=epochs, calls=calls), epochs))


def _print_result(result: SweepResult, experiment: Experiment) -> None:
    from attopt.experiments.sweep.check import integrity_groups
    from attopt.experiments.sweep.report import failure_digest
    from attopt.experiments.sweep.tasks import setting_columns

    summary = result.summary
    keys = list(summary.columns[: summary.columns.get_loc("n_rows")])
    shown = summary[[*keys, *(c for c in SUMMARY_COLUMNS if c in summary.columns)]]
    typer.echo(f"\nResults in {result.out_dir}/ (summary.csv, report.md, failures.csv, rows/)\n")
    typer.echo(shown.to_string(index=False, float_format="{:.4g}".format))
    typer.echo(
        f"\n{result.n_total} trials: {result.n_computed} computed now, "
        f"{result.n_resumed} already done, {result.n_failed} failed, "
        f"{result.n_missing} missing ({result.elapsed_s:.1f} s)"
    )
    if len(result.rows):
        columns = setting_columns(result.settings)
        _echo_worst_share(result.rows, integrity_groups(result.rows, columns, experiment.group_by))
    for line in result.dropped_chunks:
        typer.echo(f"  warning: {line}", err=True)
    if len(result.code_versions) > 1:
        versions = ", ".join(f"{code} ({n})" for code, n in result.code_versions.items())
        typer.echo(f"  trials computed by several code versions: {versions}")
    for line in failure_digest(result.failures):
        typer.echo(f"  failed: {line}")
    for error in result.errors[:MAX_ERRORS_SHOWN]:
        typer.echo(f"  not finished: {error}", err=True)
    if len(result.errors) > MAX_ERRORS_SHOWN:
        typer.echo(f"  ... and {len(result.errors) - MAX_ERRORS_SHOWN} more chunks", err=True)
    if not result.complete:
        typer.echo("Some trials did not finish: rerun the same command to complete them.", err=True)
