"""Sweep store: a damaged chunk is found on resume, named, dropped and recomputed exactly."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow.parquet as pq
import pytest
from pandas.testing import assert_frame_equal
from typer.testing import CliRunner

from attopt.experiments.cli import app
from attopt.experiments.sweep import SweepResult, run_sweep
from tests.sweep_toys import TOY

TRIALS = 4
CHUNK_SIZE = 2  # 3 settings x 4 trials: six chunks of two trials

Damage = Callable[[Path, str, str], None]
"""Damages the results directory, given the damaged chunk and another chunk."""


def sweep(out: Path) -> SweepResult:
    """Run (or resume) the toy sweep in this process, in chunks of two trials."""
    return run_sweep(TOY, trials=TRIALS, out=out, workers=1, chunk_size=CHUNK_SIZE, progress=False)


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> SweepResult:
    """A finished toy sweep, copied by each test before damaging it."""
    result = sweep(tmp_path_factory.mktemp("finished"))
    assert result.complete and not result.dropped_chunks
    return result


def assert_bitwise_equal(rows: pd.DataFrame, expected: pd.DataFrame) -> None:
    """Equal frames, the floats bit for bit (NaN payloads and signed zeros included)."""
    assert_frame_equal(rows, expected, check_exact=True)
    for column in expected.select_dtypes("floating"):
        assert rows[column].to_numpy().tobytes() == expected[column].to_numpy().tobytes()


def rows_file(out: Path, chunk: str) -> Path:
    return out / "rows" / f"{chunk}.parquet"


def record_file(out: Path, chunk: str) -> Path:
    return out / "trials" / f"{chunk}.json"


def truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def edit_record(out: Path, chunk: str, change: Callable[[dict[str, Any]], None]) -> None:
    path = record_file(out, chunk)
    record = json.loads(path.read_text())
    change(record)
    path.write_text(json.dumps(record))


def without_checksums(damage: Damage) -> Damage:
    """``damage`` to a directory whose records carry no rows SHA-256 (older records)."""

    def damaged(out: Path, chunk: str, other: str) -> None:
        for path in (out / "trials").glob("*.json"):
            edit_record(out, path.stem, lambda record: record.pop("rows_sha256"))
        damage(out, chunk, other)

    return damaged


def truncate_rows(out: Path, chunk: str, other: str) -> None:
    truncate(rows_file(out, chunk))


def empty_rows(out: Path, chunk: str, other: str) -> None:
    rows_file(out, chunk).write_bytes(b"")


def delete_rows(out: Path, chunk: str, other: str) -> None:
    rows_file(out, chunk).unlink()


def swap_rows(out: Path, chunk: str, other: str) -> None:
    shutil.copy(rows_file(out, other), rows_file(out, chunk))


def halve_rows(out: Path, chunk: str, other: str) -> None:
    table = pq.read_table(rows_file(out, chunk))
    pq.write_table(table.slice(0, table.num_rows // 2), rows_file(out, chunk))


def drop_trial_index(out: Path, chunk: str, other: str) -> None:
    table = pq.read_table(rows_file(out, chunk))
    pq.write_table(table.drop_columns(["trial_index"]), rows_file(out, chunk))


def truncate_record(out: Path, chunk: str, other: str) -> None:
    truncate(record_file(out, chunk))


def empty_record(out: Path, chunk: str, other: str) -> None:
    record_file(out, chunk).write_bytes(b"")


def swap_record(out: Path, chunk: str, other: str) -> None:
    shutil.copy(record_file(out, other), record_file(out, chunk))


def delete_record(out: Path, chunk: str, other: str) -> None:
    record_file(out, chunk).unlink()


def repeat_a_trial(out: Path, chunk: str, other: str) -> None:
    edit_record(out, chunk, lambda record: record["tasks"].append(record["tasks"][0]))


def name_a_fourth_setting(out: Path, chunk: str, other: str) -> None:
    edit_record(out, chunk, lambda record: record["tasks"][0].__setitem__(0, 3))


def add_a_foreign_failure(out: Path, chunk: str, other: str) -> None:
    failure = {
        "setting_index": 0,
        "trial_index": 99,
        "error_type": "ValueError",
        "message": "not a trial of this chunk",
        "traceback": "",
        "seed_entropy": 0,
        "seed": "SeedSequence(0, spawn_key=(0, 99))",
    }
    edit_record(out, chunk, lambda record: record["failures"].append(failure))


def copy_chunk(out: Path, chunk: str, other: str) -> None:
    """A second chunk, sorted after the first, holding the same trials and rows."""
    shutil.copy(rows_file(out, chunk), rows_file(out, "zz-copy"))
    shutil.copy(record_file(out, chunk), record_file(out, "zz-copy"))
    edit_record(out, "zz-copy", lambda record: record.__setitem__("chunk", "zz-copy"))


ROWS = "rows/{chunk}.parquet"
RECORD = "trials/{chunk}.json"
CHANGED = "changed since it was written"


@pytest.mark.parametrize(
    ("damage", "file", "problem", "recomputed"),
    [
        pytest.param(truncate_rows, ROWS, CHANGED, 2, id="truncated-rows"),
        pytest.param(empty_rows, ROWS, CHANGED, 2, id="zero-byte-rows"),
        pytest.param(swap_rows, ROWS, CHANGED, 2, id="rows-of-another-chunk"),
        pytest.param(delete_rows, ROWS, "missing (its record holds 12 rows)", 2, id="no-rows"),
        pytest.param(
            without_checksums(truncate_rows),
            ROWS,
            "not readable parquet (",
            2,
            id="truncated-rows-no-checksum",
        ),
        pytest.param(
            without_checksums(empty_rows),
            ROWS,
            "not readable parquet (",
            2,
            id="zero-byte-rows-no-checksum",
        ),
        pytest.param(
            without_checksums(swap_rows),
            ROWS,
            "which its record does not list as succeeded",
            2,
            id="rows-of-another-chunk-no-checksum",
        ),
        pytest.param(
            without_checksums(halve_rows),
            ROWS,
            "holds 6 rows, its record 12",
            2,
            id="half-the-rows-no-checksum",
        ),
        pytest.param(
            without_checksums(drop_trial_index),
            ROWS,
            "has no integer setting_index and trial_index columns",
            2,
            id="no-index-column-no-checksum",
        ),
        pytest.param(
            truncate_record, RECORD, "not a chunk record (Invalid JSON", 2, id="truncated-record"
        ),
        pytest.param(
            empty_record, RECORD, "not a chunk record (Invalid JSON", 2, id="zero-byte-record"
        ),
        pytest.param(
            swap_record, RECORD, "holds the record of chunk", 2, id="record-of-another-chunk"
        ),
        pytest.param(delete_record, ROWS, "the rows of no finished chunk", 2, id="no-record"),
        pytest.param(repeat_a_trial, RECORD, "lists a trial twice", 2, id="trial-listed-twice"),
        pytest.param(
            name_a_fourth_setting,
            RECORD,
            "lists a setting beyond the sweep's 3",
            2,
            id="setting-out-of-range",
        ),
        pytest.param(
            add_a_foreign_failure,
            RECORD,
            "records failures of trials it does not list",
            2,
            id="failure-of-another-trial",
        ),
        pytest.param(
            copy_chunk, "trials/zz-copy.json", "of chunk {chunk}", 0, id="trials-of-another-chunk"
        ),
    ],
)
def test_damaged_chunk_is_named_dropped_and_recomputed_bit_for_bit(
    tmp_path: Path,
    finished: SweepResult,
    damage: Damage,
    file: str,
    problem: str,
    recomputed: int,
) -> None:
    out = tmp_path / "out"
    shutil.copytree(finished.out_dir, out)
    chunk, other = sorted(p.stem for p in (out / "trials").glob("*.json"))[2:4]
    damage(out, chunk, other)

    resumed = sweep(out)

    [line] = resumed.dropped_chunks
    assert line.startswith(file.format(chunk=chunk) + ": "), line
    assert problem.format(chunk=chunk) in line
    assert resumed.complete and resumed.n_computed == recomputed
    assert resumed.n_resumed == finished.n_total - recomputed
    assert_bitwise_equal(resumed.rows, finished.rows)
    assert len(pd.read_parquet(out / "rows")) == len(finished.rows)  # nothing stale is left
    again = sweep(out)
    assert not again.dropped_chunks and again.n_computed == 0
    assert_bitwise_equal(again.rows, finished.rows)


def test_a_record_key_of_another_code_version_is_no_damage(
    tmp_path: Path, finished: SweepResult
) -> None:
    out = tmp_path / "out"
    shutil.copytree(finished.out_dir, out)
    for path in (out / "trials").glob("*.json"):
        edit_record(out, path.stem, lambda record: record.__setitem__("added_later", [1, 2]))

    resumed = sweep(out)

    assert not resumed.dropped_chunks and resumed.n_computed == 0
    assert_bitwise_equal(resumed.rows, finished.rows)


def test_records_hold_the_checksum_of_their_rows(finished: SweepResult) -> None:
    """Each record's ``rows_sha256`` is that of its rows file, so a changed byte is found."""
    out = finished.out_dir
    for path in (out / "trials").glob("*.json"):
        record = json.loads(path.read_text())
        data = rows_file(out, path.stem).read_bytes()
        assert record["rows_sha256"] == hashlib.sha256(data).hexdigest()


def test_cli_warns_of_a_damaged_chunk_and_completes_the_sweep(tmp_path: Path) -> None:
    command = ["run", "tests.sweep_toys:TOY", "--quick", "--workers", "1", "--chunk-size", "1"]
    command += ["--out", str(tmp_path), "--no-progress"]
    runner = CliRunner()
    assert runner.invoke(app, command).exit_code == 0
    damaged = sorted((tmp_path / "rows").glob("*.parquet"))[0]
    original = pd.read_parquet(damaged)
    truncate(damaged)

    result = runner.invoke(app, command)

    assert result.exit_code == 0, result.output
    assert f"  warning: rows/{damaged.name}: {CHANGED}" in result.stderr
    assert f"chunk {damaged.stem} dropped, its trials are computed again" in result.stderr
    assert "2 trials: 1 computed now, 1 already done, 0 failed, 0 missing" in result.output
    assert_bitwise_equal(pd.read_parquet(damaged), original)
