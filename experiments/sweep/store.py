"""The output directory of a sweep: manifest, finished chunks, resume.

Layout of ``out``::

    manifest.json          experiment, parameters, settings, seed, trials, hash, code
    rows/<chunk>.parquet   rows of the chunk's trials (absent if it has none)
    trials/<chunk>.json    the chunk's record (:class:`ChunkRecord`): its (setting, trial)
                           pairs, row count, failures, code and the rows file's SHA-256

``code`` is the version of the code that wrote the chunk (or last opened the
directory, in the manifest), :func:`code_version`: a resumed sweep may mix
chunks of several versions, and :meth:`SweepStore.code_versions` says which.

A chunk counts as finished once its ``trials/<chunk>.json`` record exists.
Both files are written to a temporary name and renamed, the rows first, so an
interruption at any point leaves either a finished chunk or nothing that is
read back.  Opening the directory checks every finished chunk against its
record (:meth:`SweepStore.drop_damaged_chunks`): a chunk that cannot be read
back as it was written (a truncated or emptied file, rows that are not the
record's) is deleted, so that its trials are computed again.  The manifest's
hash covers the experiment name, parameters, settings and root seed:
reopening the directory with different ones is refused unless ``fresh``
discards the old results.  The number of trials is
not part of the hash: asking for more trials adds the missing ones, asking for
fewer reads back only those.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import BaseModel, ConfigDict, NonNegativeInt, ValidationError

from attopt.experiments.config.schema import flat_items
from attopt.experiments.experiment import Setting
from attopt.experiments.sweep.tasks import ChunkResult, Task, scalar_setting_items

MANIFEST = "manifest.json"
ROWS_DIR = "rows"
RECORDS_DIR = "trials"
OUTPUT_FILES = ("summary.csv", "failures.csv", "report.md")
FORMAT_VERSION = 1
INDEX_COLUMNS = ("setting_index", "trial_index")


UNRECORDED = "unrecorded"
"""The code version of a chunk written before versions were recorded."""


class FailureRecord(BaseModel):
    """A trial that raised (:func:`~attopt.experiments.sweep.tasks.failure_record`)."""

    model_config = ConfigDict(strict=True, extra="allow", frozen=True)

    setting_index: NonNegativeInt
    trial_index: NonNegativeInt
    error_type: str
    message: str
    traceback: str
    seed_entropy: int
    seed: str


FAILURE_COLUMNS = tuple(FailureRecord.model_fields)


class ChunkRecord(BaseModel):
    """``trials/<chunk>.json``: what a finished chunk computed.

    ``rows_sha256`` is the SHA-256 of ``rows/<chunk>.parquet`` as written
    (None when the chunk has no rows, or was written before it was recorded).
    Keys this version does not know (written by another one) are kept, not
    taken for damage.
    """

    model_config = ConfigDict(strict=True, extra="allow", frozen=True)

    chunk: str
    tasks: list[tuple[NonNegativeInt, NonNegativeInt]]
    n_rows: NonNegativeInt
    failures: list[FailureRecord]
    elapsed_s: float
    code: str = UNRECORDED
    rows_sha256: str | None = None


class DamagedChunkError(ValueError):
    """A stored chunk that cannot be read back as it was written (the message names the file)."""


def code_version() -> str:
    """``git describe --always --dirty`` of the checkout this package runs from (a commit
    hash, ``-dirty`` with uncommitted changes), or ``unknown`` outside a git checkout."""
    root = Path(__file__).resolve().parents[2]
    try:
        described = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=12"],
            capture_output=True,
            text=True,
            timeout=30,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return described.stdout.strip() or "unknown"


class ManifestMismatchError(ValueError):
    """The output directory holds results of different parameters, settings or seed."""


@dataclass(frozen=True)
class SweepIdentity:
    """What determines a sweep's results (everything but the number of trials)."""

    experiment: str
    parameters: Mapping[str, Any]
    settings: Sequence[Setting]
    seed: int

    def as_dict(self) -> dict[str, Any]:
        """Return the identity as JSON-compatible data."""
        return json.loads(_canonical_json(self._fields()))

    def digest(self) -> str:
        """Return the SHA-256 of the canonical JSON of the identity."""
        return hashlib.sha256(_canonical_json(self._fields()).encode()).hexdigest()

    def _fields(self) -> dict[str, Any]:
        return {
            "experiment": self.experiment,
            "parameters": dict(self.parameters),
            "settings": list(self.settings),
            "seed": self.seed,
        }


class SweepStore:
    """Reads and writes the results of one sweep in an output directory."""

    def __init__(self, out: Path, identity: SweepIdentity) -> None:
        self.out = Path(out)
        self.identity = identity
        self.rows_dir = self.out / ROWS_DIR
        self.records_dir = self.out / RECORDS_DIR
        self.code = code_version()
        self.dropped: list[str] = []
        """What :meth:`drop_damaged_chunks` deleted on opening the directory, one line each."""

    @classmethod
    def open(
        cls,
        out: Path,
        identity: SweepIdentity,
        *,
        reference: str,
        trials: int,
        fresh: bool = False,
    ) -> SweepStore:
        """Open ``out`` for ``identity``, creating it, resuming it, or (``fresh``) clearing it.

        Raises :class:`ManifestMismatchError` when ``out`` holds results of
        another identity and ``fresh`` is false.
        """
        store = cls(out, identity)
        previous = store.read_manifest()
        if not fresh and previous is None and any(store.records_dir.glob("*.json")):
            raise ManifestMismatchError(
                f"{store.out} holds finished chunks but no {MANIFEST}, so they cannot be "
                "matched to this sweep; pass --fresh (fresh=True) to discard them"
            )
        if not fresh and previous is not None and previous.get("hash") != identity.digest():
            raise ManifestMismatchError(_mismatch_message(store.out, previous, identity))
        if fresh:
            store.clear()
        store.rows_dir.mkdir(parents=True, exist_ok=True)
        store.records_dir.mkdir(parents=True, exist_ok=True)
        store._remove_temporary_files()
        store.dropped = store.drop_damaged_chunks()
        created = previous.get("created") if previous and not fresh else None
        store._write_manifest(reference=reference, trials=trials, created=created)
        return store

    def read_manifest(self) -> dict[str, Any] | None:
        """Return the manifest of the directory, or None if there is none."""
        path = self.out / MANIFEST
        if not path.exists():
            return None
        return json.loads(path.read_text())

    def clear(self) -> None:
        """Delete the files a sweep writes (and only those) from the directory."""
        for directory, suffix in ((self.rows_dir, ".parquet"), (self.records_dir, ".json")):
            if directory.is_dir():
                for path in directory.iterdir():
                    if path.name.endswith((suffix, ".tmp")):
                        path.unlink()
        for name in (MANIFEST, *OUTPUT_FILES):
            (self.out / name).unlink(missing_ok=True)

    def commit(self, result: ChunkResult) -> None:
        """Store a finished chunk: its rows, then the record that marks it finished."""
        rows_sha256 = None
        if result.n_rows:
            rows_sha256 = hashlib.sha256(result.rows).hexdigest()
            path = self._rows_path(result.chunk_id)
            _temporary(path).write_bytes(result.rows)
            os.replace(_temporary(path), path)
        record = ChunkRecord(
            chunk=result.chunk_id,
            tasks=list(result.tasks),
            n_rows=result.n_rows,
            failures=result.failures,
            elapsed_s=result.elapsed_s,
            code=self.code,
            rows_sha256=rows_sha256,
        )
        path = self.records_dir / f"{result.chunk_id}.json"
        _temporary(path).write_text(record.model_dump_json())
        os.replace(_temporary(path), path)

    def drop_damaged_chunks(self) -> list[str]:
        """Delete every stored chunk that cannot be read back as it was written; say which.

        A chunk is damaged when its record is not readable as a
        :class:`ChunkRecord` of its name, lists a trial twice, outside the
        settings or held by another chunk, or records failures that are not one
        per trial it lists; or when its rows file is missing, differs from the
        SHA-256 the record holds, is not readable parquet, or holds other rows
        than the record's (another number of rows, rows of a trial the record
        does not list as succeeded).  Both files of a damaged chunk are deleted,
        so that its trials are computed again; so is a rows file that belongs
        to no finished chunk (left by an interrupted write or a deleted record).
        Returns one line per deletion naming the file and what was wrong.
        """
        dropped: list[str] = []
        owners: dict[Task, str] = {}
        with_rows: set[str] = set()
        for path in sorted(self.records_dir.glob("*.json")):
            try:
                record = self._checked_record(path, owners)
            except DamagedChunkError as damage:
                path.unlink()
                self._rows_path(path.stem).unlink(missing_ok=True)
                dropped.append(
                    f"{damage}; chunk {path.stem} dropped, its trials are computed again"
                )
                continue
            owners.update(dict.fromkeys(record.tasks, record.chunk))
            if record.n_rows:
                with_rows.add(record.chunk)
        for path in sorted(self.rows_dir.glob("*.parquet")):
            if path.stem not in with_rows:
                path.unlink()
                dropped.append(
                    f"{ROWS_DIR}/{path.name}: the rows of no finished chunk (left by an "
                    "interrupted write or a deleted record); deleted"
                )
        return dropped

    def finished_tasks(self, trials: int) -> set[Task]:
        """Return the ``(setting, trial)`` pairs already finished (succeeded or failed)."""
        return {(s, t) for record in self._records() for s, t in record.tasks if t < trials}

    def code_versions(self, trials: int) -> dict[str, int]:
        """Finished trials among the first ``trials`` per code version that computed them."""
        counts = Counter(
            record.code for record in self._records() for _, t in record.tasks if t < trials
        )
        return dict(counts.most_common())

    def load_rows(self, trials: int) -> pd.DataFrame:
        """Return the stored rows of the first ``trials`` trials, in (setting, trial, row) order."""
        tables = [
            pq.read_table(self._rows_path(record.chunk))
            for record in self._records()
            if record.n_rows
        ]
        if not tables:
            return pd.DataFrame()
        rows = pa.concat_tables(tables, promote_options="permissive").to_pandas()
        rows = rows[rows["trial_index"] < trials]
        rows = rows.sort_values(["setting_index", "trial_index"], kind="stable")
        return rows.reset_index(drop=True)

    def load_failures(self, trials: int) -> pd.DataFrame:
        """Return the failure records of the first ``trials`` trials with their setting columns."""
        settings = self.identity.settings
        failures = [
            {**failure.model_dump(), **scalar_setting_items(settings[failure.setting_index])}
            for record in self._records()
            for failure in record.failures
            if failure.trial_index < trials
        ]
        frame = pd.DataFrame(failures, columns=None if failures else list(FAILURE_COLUMNS))
        if failures:
            frame = frame.sort_values(["setting_index", "trial_index"], kind="stable")
        return frame.reset_index(drop=True)

    def _records(self) -> Iterator[ChunkRecord]:
        for path in sorted(self.records_dir.glob("*.json")):
            yield ChunkRecord.model_validate_json(path.read_bytes())

    def _rows_path(self, chunk: str) -> Path:
        return self.rows_dir / f"{chunk}.parquet"

    def _checked_record(self, path: Path, owners: Mapping[Task, str]) -> ChunkRecord:
        """Return the record at ``path`` if its chunk reads back as written (trials
        held by earlier chunks in ``owners``), else raise :class:`DamagedChunkError`."""
        name = f"{RECORDS_DIR}/{path.name}"
        try:
            record = ChunkRecord.model_validate_json(path.read_bytes())
        except ValidationError as error:
            raise DamagedChunkError(f"{name}: not a chunk record ({_first_error(error)})") from None
        tasks = set(record.tasks)
        failed = [(failure.setting_index, failure.trial_index) for failure in record.failures]
        shared = sorted(tasks & owners.keys())
        n_settings = len(self.identity.settings)
        if record.chunk != path.stem:
            raise DamagedChunkError(f"{name}: holds the record of chunk {record.chunk}")
        if len(tasks) < len(record.tasks):
            raise DamagedChunkError(f"{name}: lists a trial twice")
        if any(s >= n_settings for s, _ in tasks):
            raise DamagedChunkError(f"{name}: lists a setting beyond the sweep's {n_settings}")
        if shared:
            raise DamagedChunkError(f"{name}: lists trial {shared[0]} of chunk {owners[shared[0]]}")
        if len(set(failed)) < len(failed) or not tasks.issuperset(failed):
            raise DamagedChunkError(f"{name}: records failures of trials it does not list")
        if record.n_rows:
            self._check_rows(record, tasks.difference(failed))
        return record

    def _check_rows(self, record: ChunkRecord, succeeded: set[Task]) -> None:
        """Raise :class:`DamagedChunkError` unless the rows file holds ``record``'s rows."""
        path = self._rows_path(record.chunk)
        name = f"{ROWS_DIR}/{path.name}"
        if not path.exists():
            raise DamagedChunkError(f"{name}: missing (its record holds {record.n_rows} rows)")
        data = path.read_bytes()
        if record.rows_sha256 not in (None, hashlib.sha256(data).hexdigest()):
            raise DamagedChunkError(
                f"{name}: changed since it was written ({len(data)} bytes whose SHA-256 is "
                "not the record's; truncated or overwritten)"
            )
        try:
            table = pq.read_table(pa.BufferReader(data))
        except pa.ArrowException as error:
            raise DamagedChunkError(f"{name}: not readable parquet ({error})") from None
        if table.num_rows != record.n_rows:
            raise DamagedChunkError(
                f"{name}: holds {table.num_rows} rows, its record {record.n_rows}"
            )
        if not all(
            column in table.column_names
            and pa.types.is_integer(table.schema.field(column).type)
            and table[column].null_count == 0
            for column in INDEX_COLUMNS
        ):
            raise DamagedChunkError(f"{name}: has no integer {' and '.join(INDEX_COLUMNS)} columns")
        index = np.unique(np.column_stack([table[c].to_numpy() for c in INDEX_COLUMNS]), axis=0)
        strays = sorted({(int(s), int(t)) for s, t in index} - succeeded)
        if strays:
            raise DamagedChunkError(
                f"{name}: holds rows of trial {strays[0]}, which its record does not list "
                "as succeeded"
            )

    def _write_manifest(self, *, reference: str, trials: int, created: str | None) -> None:
        now = datetime.now(UTC).isoformat(timespec="seconds")
        manifest = {
            "format": FORMAT_VERSION,
            **self.identity.as_dict(),
            "reference": reference,
            "trials": trials,
            "hash": self.identity.digest(),
            "created": created or now,
            "updated": now,
            "code": self.code,
        }
        path = self.out / MANIFEST
        _temporary(path).write_text(json.dumps(manifest, indent=2) + "\n")
        os.replace(_temporary(path), path)

    def _remove_temporary_files(self) -> None:
        for directory in (self.rows_dir, self.records_dir):
            for path in directory.glob("*.tmp"):
                path.unlink()


def _temporary(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")


def _first_error(error: ValidationError) -> str:
    first = error.errors()[0]
    where = ".".join(str(part) for part in first["loc"])
    return f"{where}: {first['msg']}" if where else first["msg"]


def _canonical_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=repr)


def _mismatch_message(out: Path, manifest: Mapping[str, Any], identity: SweepIdentity) -> str:
    new = identity.as_dict()
    differences = []
    if manifest.get("experiment") != new["experiment"]:
        differences.append(f"experiment {manifest.get('experiment')!r} -> {new['experiment']!r}")
    if manifest.get("seed") != new["seed"]:
        differences.append(f"seed {manifest.get('seed')} -> {new['seed']}")
    old_parameters = flat_items(manifest.get("parameters", {}))
    new_parameters = flat_items(new["parameters"])
    for key in sorted(set(old_parameters) | set(new_parameters)):
        if old_parameters.get(key) != new_parameters.get(key):
            old_value, new_value = old_parameters.get(key), new_parameters.get(key)
            differences.append(f"parameter {key!r} {old_value!r} -> {new_value!r}")
    if not differences:
        differences.append("the experiment's settings (its grid) changed")
    return (
        f"{out} holds results of a different sweep ({'; '.join(differences)}); "
        "pass --fresh (fresh=True) to discard them, or choose another --out directory"
    )
