"""Run an experiment's grid x trials on an engine, store, resume, summarise, report."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from attopt.experiments.config import resolve_parameters, starter_toml
from attopt.experiments.experiment import Experiment, ReportContext, Setting
from attopt.experiments.registry import display_name, reference_of
from attopt.experiments.reporting.integrity import integrity_section
from attopt.experiments.sweep.aggregate import invalid_reasons, summarise
from attopt.experiments.sweep.check import integrity_groups
from attopt.experiments.sweep.engines import Engine, make_engine
from attopt.experiments.sweep.report import RunDescription, render_report
from attopt.experiments.sweep.seeding import check_root_seed
from attopt.experiments.sweep.store import SweepIdentity, SweepStore
from attopt.experiments.sweep.tasks import (
    ChunkResult,
    ChunkSpec,
    default_chunk_size,
    plan_chunks,
    setting_columns,
)
from attopt.solvers.compilation import loop_names

CONFIG_FILE = "config.toml"
"""The effective parameters of a sweep, written into its output directory."""


@dataclass(frozen=True)
class SweepResult:
    """What a sweep produced (everything is also written to ``out_dir``).

    ``rows`` holds every stored row of the requested trials in (setting, trial,
    row) order; ``failures`` one row per trial that raised.  ``n_computed``
    trials ran in this call, ``n_resumed`` were already on disk, ``n_missing``
    did not finish (see ``errors``; rerun to complete them).
    """

    out_dir: Path
    experiment: str
    parameters: dict[str, Any]
    settings: list[Setting]
    trials: int
    seed: int
    rows: pd.DataFrame
    summary: pd.DataFrame
    failures: pd.DataFrame
    n_total: int
    n_computed: int
    n_resumed: int
    n_failed: int
    n_missing: int
    errors: list[str]
    elapsed_s: float
    code_versions: dict[str, int]
    """Finished trials per version of the code that computed them
    (:func:`~attopt.experiments.sweep.store.code_version`)."""
    dropped_chunks: list[str]
    """One line per damaged file found in ``out_dir`` on resuming (a truncated or emptied
    chunk, rows that are not its record's), naming it and what was wrong; its chunk was
    deleted and its trials computed again, within ``n_computed``
    (:meth:`~attopt.experiments.sweep.store.SweepStore.drop_damaged_chunks`)."""

    @property
    def complete(self) -> bool:
        """Whether every requested trial finished (successfully or with a recorded failure)."""
        return self.n_missing == 0


def run_sweep(
    experiment: Experiment,
    *,
    trials: int | None = None,
    engine: str = "local",
    address: str | None = None,
    workers: int | None = None,
    seed: int = 0,
    out: Path,
    quick: bool = False,
    config: Path | None = None,
    progress: bool = True,
    fresh: bool = False,
    chunk_size: int | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> SweepResult:
    """Run ``trials`` Monte Carlo trials of every setting of ``experiment`` and summarise them.

    Parameters are the experiment's, then its quick variant (``quick``), then
    the TOML file ``config``, then ``overrides``, validated by the experiment's
    schema (:func:`~attopt.experiments.config.resolve_parameters`); the effective
    parameters are written to ``out/config.toml``, a config that reruns the sweep.
    Trial ``j`` of setting ``i`` is seeded with
    ``SeedSequence(seed, spawn_key=(i, j))``.  ``trials=None`` means the
    experiment's ``default_trials`` (``quick_trials`` with ``quick``).

    ``engine`` is ``"local"`` (process pool of ``workers`` processes, default
    one per CPU; one worker runs in this process) or ``"dask"`` (a LocalCluster
    of ``workers`` processes, or the scheduler at ``address``).  Finished
    chunks are written to ``out`` as they arrive; rerunning into the same
    ``out`` computes only the missing trials, and refuses results of other
    parameters or seed unless ``fresh``.  Writes ``summary.csv``,
    ``failures.csv`` and ``report.md`` (followed by the experiment's report).
    """
    started = time.perf_counter()
    check_root_seed(seed)
    reference = reference_of(experiment)
    validated = resolve_parameters(experiment, quick=quick, config=config, overrides=overrides)
    parameters = validated.model_dump(mode="json")
    settings = _checked_settings(experiment.grid(parameters))
    if trials is None:
        trials = experiment.quick_trials if quick else experiment.default_trials
    if trials < 1:
        raise ValueError(f"trials must be at least 1, got {trials}")
    runner = make_engine(engine, workers=workers, address=address)
    store = SweepStore.open(
        out,
        SweepIdentity(experiment.name, parameters, settings, seed),
        reference=reference,
        trials=trials,
        fresh=fresh,
    )
    command = _command(reference, trials, seed, quick, config, overrides)
    (store.out / CONFIG_FILE).write_text(
        starter_toml(validated, f"Effective parameters of: {command}")
    )
    finished = store.finished_tasks(trials)
    pending = [
        (s, t) for t in range(trials) for s in range(len(settings)) if (s, t) not in finished
    ]
    computed, errors = 0, []
    if pending:
        with runner:
            specs = plan_chunks(
                pending,
                chunk_size=chunk_size or default_chunk_size(len(pending), runner.workers),
                experiment=reference,
                root_seed=seed,
                settings=settings,
            )
            with tqdm(
                total=len(settings) * trials,
                initial=len(finished),
                desc=experiment.name,
                unit="trial",
                disable=not progress,
                dynamic_ncols=True,
            ) as bar:
                computed, errors = _execute(
                    runner, specs, store, bar, loop_names(experiment.compiled_loops)
                )
    rows = store.load_rows(trials)
    failures = store.load_failures(trials)
    columns = setting_columns(settings)
    summary = summarise(
        rows,
        failures,
        setting_columns=columns,
        group_by=experiment.group_by,
        extra=experiment.summary_columns,
    )
    n_total = len(settings) * trials
    n_missing = n_total - len(store.finished_tasks(trials))
    code_versions = store.code_versions(trials)
    description = RunDescription(
        name=experiment.name,
        summary=experiment.summary,
        command=command,
        parameters=parameters,
        n_settings=len(settings),
        trials=trials,
        seed=seed,
        n_finished=n_total - n_missing,
        n_failed=len(failures),
        n_missing=n_missing,
        code_versions=code_versions,
    )
    _write_outputs(store.out, experiment, description, rows, summary, failures, columns)
    return SweepResult(
        out_dir=store.out,
        experiment=experiment.name,
        parameters=parameters,
        settings=settings,
        trials=trials,
        seed=seed,
        rows=rows,
        summary=summary,
        failures=failures,
        n_total=n_total,
        n_computed=computed,
        n_resumed=len(finished),
        n_failed=len(failures),
        n_missing=n_missing,
        errors=errors,
        elapsed_s=time.perf_counter() - started,
        code_versions=code_versions,
        dropped_chunks=store.dropped,
    )


def _execute(
    runner: Engine, specs: list[ChunkSpec], store: SweepStore, bar: tqdm, loops: list[str]
) -> tuple[int, list[str]]:
    """Compile the numba ``loops`` on the workers, run the chunks, storing each as it
    finishes; return trials done and chunk errors."""
    computed, failed, errors = 0, 0, []
    for spec, outcome in runner.run(specs, loops):
        if isinstance(outcome, ChunkResult):
            store.commit(outcome)
            computed += len(outcome.tasks)
            failed += len(outcome.failures)
            bar.update(len(outcome.tasks))
            bar.set_postfix(failed=failed, refresh=False)
        else:
            errors.append(
                f"chunk {spec.chunk_id} ({len(spec.tasks)} trials) did not finish: "
                f"{type(outcome).__name__}: {outcome}"
            )
    return computed, errors


def _checked_settings(settings: Any) -> list[Setting]:
    if not isinstance(settings, list) or not all(isinstance(s, dict) for s in settings):
        raise TypeError("experiment.grid must return a list of dicts")
    if not settings:
        raise ValueError("experiment.grid returned no settings")
    return settings


def _command(
    reference: str,
    trials: int,
    seed: int,
    quick: bool,
    config: Path | None,
    overrides: Mapping[str, Any] | None,
) -> str:
    command = f"attopt run {display_name(reference)} --trials {trials} --seed {seed}"
    if quick:
        command += " --quick"
    if config is not None:
        command += f" --config {config}"
    if overrides:
        command += f"  # plus overrides {dict(overrides)!r} given through the Python API"
    return command


def _write_outputs(
    out: Path,
    experiment: Experiment,
    description: RunDescription,
    rows: pd.DataFrame,
    summary: pd.DataFrame,
    failures: pd.DataFrame,
    columns: list[str],
) -> None:
    summary.to_csv(out / "summary.csv", index=False)
    failures.to_csv(out / "failures.csv", index=False)
    reasons = invalid_reasons(rows, experiment.group_by)
    integrity = ""
    if experiment.report is None and len(rows):
        by = integrity_groups(rows, columns, experiment.group_by)
        integrity = integrity_section(rows, by, description.command)
    report = render_report(description, summary, reasons, failures, integrity)
    (out / "report.md").write_text(report)
    if experiment.report is not None and len(rows):  # (no rows: every trial failed)
        context = ReportContext(
            parameters=description.parameters,
            rows=rows,
            summary=summary,
            out_dir=out,
            command=description.command,
        )
        (out / "report.md").write_text(report + "\n" + experiment.report(context))
