"""Chunks of trials: what is sent to a worker and what comes back.

A :class:`ChunkSpec` carries only plain data (the experiment's import path, the
root seed, the ``(setting_index, trial_index)`` pairs and the settings they
use).  The worker imports the experiment once per process, runs the trials in
order and returns their rows as the Parquet file the store writes; a trial that
raises is recorded as a failure and the chunk goes on.
"""

from __future__ import annotations

import copy
import math
import time
import traceback
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from attopt.experiments.experiment import Experiment, Row, Setting
from attopt.experiments.registry import get_experiment
from attopt.experiments.sweep.seeding import describe_seed, trial_seed

Task = tuple[int, int]
"""``(setting_index, trial_index)``."""

MAX_CHUNK_SIZE = 32
CHUNKS_PER_WORKER = 16
TRACEBACK_LINES = 30


@dataclass(frozen=True)
class ChunkSpec:
    """A group of trials executed together by one worker."""

    chunk_id: str
    experiment: str
    root_seed: int
    tasks: tuple[Task, ...]
    settings: Mapping[int, Setting]


@dataclass(frozen=True)
class ChunkResult:
    """The rows and failures of a finished chunk.

    The rows travel as the Parquet file the store writes (:func:`parquet_bytes`): the
    worker converts them, so the process that collects the chunks only writes bytes, and
    what a worker sends is the compressed file, not the pickled frame (about a third of
    its size for ``wahba-mag-sun``'s rows).
    """

    chunk_id: str
    tasks: tuple[Task, ...]
    rows: bytes
    n_rows: int
    failures: list[dict[str, Any]]
    elapsed_s: float


def parquet_bytes(rows: pd.DataFrame) -> bytes:
    """``rows`` as a Parquet file (pyarrow's defaults, no index)."""
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pandas(rows, preserve_index=False), sink)
    return sink.getvalue().to_pybytes()


def default_chunk_size(n_tasks: int, workers: int) -> int:
    """Return a chunk size giving each worker several chunks, at most ``MAX_CHUNK_SIZE``."""
    return max(1, min(MAX_CHUNK_SIZE, math.ceil(n_tasks / (CHUNKS_PER_WORKER * max(workers, 1)))))


def plan_chunks(
    tasks: Sequence[Task],
    *,
    chunk_size: int,
    experiment: str,
    root_seed: int,
    settings: Sequence[Setting],
) -> list[ChunkSpec]:
    """Split ``tasks`` (in order) into chunks of ``chunk_size`` trials."""
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be at least 1, got {chunk_size}")
    chunks = []
    for start in range(0, len(tasks), chunk_size):
        group = tuple(tasks[start : start + chunk_size])
        first_setting, first_trial = group[0]
        chunks.append(
            ChunkSpec(
                chunk_id=f"t{first_trial:06d}-s{first_setting:05d}-n{len(group)}",
                experiment=experiment,
                root_seed=root_seed,
                tasks=group,
                settings={s: settings[s] for s in sorted({s for s, _ in group})},
            )
        )
    return chunks


def run_chunk(spec: ChunkSpec) -> ChunkResult:
    """Run every trial of ``spec`` in order; trials that raise become failure records."""
    experiment = load_experiment(spec.experiment)
    started = time.perf_counter()
    parts: list[list[Row] | pd.DataFrame] = []
    failures = []
    for setting_index, trial_index in spec.tasks:
        setting = spec.settings[setting_index]
        seed = trial_seed(spec.root_seed, setting_index, trial_index)
        try:
            output = experiment.trial(copy.deepcopy(setting), seed)
            part = labelled_rows(output, setting, setting_index, trial_index)
        except Exception as error:
            failures.append(failure_record(error, spec.root_seed, setting_index, trial_index))
            continue
        if isinstance(part, list) and parts and isinstance(parts[-1], list):
            parts[-1].extend(part)  # one DataFrame for consecutive lists of dicts: faster
        elif len(part):
            parts.append(part)
    frames = [pd.DataFrame.from_records(p) if isinstance(p, list) else p for p in parts]
    rows = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return ChunkResult(
        chunk_id=spec.chunk_id,
        tasks=spec.tasks,
        rows=parquet_bytes(rows) if len(rows) else b"",
        n_rows=len(rows),
        failures=failures,
        elapsed_s=time.perf_counter() - started,
    )


@cache
def load_experiment(reference: str) -> Experiment:
    """Import the experiment at ``reference`` once per process."""
    return get_experiment(reference)


def scalar_setting_items(setting: Setting) -> dict[str, Any]:
    """Return the setting entries that become row columns (bool, int, float, str)."""
    return {
        key: value
        for key, value in setting.items()
        if isinstance(value, bool | int | float | str | np.bool_ | np.number | np.str_)
    }


def setting_columns(settings: Sequence[Setting]) -> list[str]:
    """The row columns of a grid's settings (:func:`scalar_setting_items`), in order."""
    return list(dict.fromkeys(k for s in settings for k in scalar_setting_items(s)))


def labelled_rows(
    output: Any, setting: Setting, setting_index: int, trial_index: int
) -> list[Row] | pd.DataFrame:
    """Return a trial's rows led by the runner's index and scalar setting columns.

    ``output`` is what the trial returned: a DataFrame or a list of dicts (kept
    as such, so that a chunk builds one DataFrame from all its dicts).
    """
    added: Row = {"setting_index": setting_index, "trial_index": trial_index}
    added.update(scalar_setting_items(setting))
    if isinstance(output, pd.DataFrame):
        _check_no_clash(added, output.columns)
        frame = output.reset_index(drop=True)
        for position, (column, value) in enumerate(added.items()):
            frame.insert(position, column, value)
        return frame
    if isinstance(output, list | tuple) and all(isinstance(row, Mapping) for row in output):
        _check_no_clash(added, set().union(*output))
        return [{**added, **row} for row in output]
    raise TypeError(
        f"trial must return a pandas DataFrame or a list of dicts, got {type(output).__name__}"
    )


def _check_no_clash(added: Row, columns: Iterable[Any]) -> None:
    clashes = sorted(set(added) & {str(column) for column in columns})
    if clashes:
        raise ValueError(f"trial returned column(s) {clashes} that the runner adds itself")


def failure_record(
    error: Exception, root_seed: int, setting_index: int, trial_index: int
) -> dict[str, Any]:
    """Return what is stored about a trial that raised ``error``."""
    lines = "".join(traceback.format_exception(error)).splitlines()
    return {
        "setting_index": setting_index,
        "trial_index": trial_index,
        "error_type": type(error).__name__,
        "message": str(error),
        "traceback": "\n".join(lines[-TRACEBACK_LINES:]),
        "seed_entropy": root_seed,
        "seed": describe_seed(root_seed, setting_index, trial_index),
    }
