"""Sweep runner: identical results across engines, resume, failures, seeding, outputs."""

from __future__ import annotations

import hashlib
import json
import os
import signal
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from pandas.testing import assert_frame_equal

from attopt.experiments.sweep import EngineSetupError, ManifestMismatchError, run_sweep
from attopt.experiments.sweep.engines import DaskEngine
from attopt.experiments.sweep.seeding import trial_index, trial_seed
from attopt.experiments.sweep.store import UNRECORDED, code_version
from attopt.experiments.sweep.tasks import ChunkSpec, run_chunk
from attopt.experiments.sweep.toys import NOOP
from tests.report_tables import row, table
from tests.sweep_toys import PROBE, TOY, TOY_WITH_REPORT


def sweep(out: Path, **options):
    """Run the toy sweep quietly with the test defaults."""
    options.setdefault("workers", 1)
    return run_sweep(TOY, out=out, progress=False, **options)


def calls(directory: Path) -> list[tuple[int, int]]:
    """The (setting, trial) of every trial call recorded by the toy."""
    return [tuple(int(x) for x in p.name.split("-")[:2]) for p in directory.iterdir()]


def test_rows_identical_across_engines_worker_counts_and_chunking(tmp_path):
    reference = sweep(tmp_path / "serial", trials=4)
    runs = {
        "local-2": sweep(tmp_path / "local2", trials=4, workers=2),
        "local-2-chunks-of-5": sweep(tmp_path / "chunks", trials=4, workers=2, chunk_size=5),
        "dask-2": sweep(tmp_path / "dask", trials=4, engine="dask", workers=2),
    }
    assert len(reference.rows) == 3 * 4 * 2 * 3
    for name, result in runs.items():
        assert result.complete, name
        assert_frame_equal(result.rows, reference.rows, check_exact=True, obj=name)
        assert_frame_equal(result.summary, reference.summary, check_exact=True, obj=name)


def test_each_trial_draws_from_its_spawned_seed_sequence(tmp_path):
    result = sweep(tmp_path, trials=3, seed=7)
    rows = result.rows[result.rows["method"] == "a"]
    for (s, t), trial in rows.groupby(["setting_index", "trial_index"]):
        rng = np.random.default_rng(np.random.SeedSequence(7, spawn_key=(s, t)))
        data = result.settings[s]["scale"] * rng.normal(size=(3, 3))
        keep = np.abs(data[:, 0]) < 1.5 * result.settings[s]["scale"]
        stored = trial[["err_x_deg", "err_y_deg", "err_z_deg"]].to_numpy()
        np.testing.assert_array_equal(stored[keep], data[keep])
        assert np.isnan(stored[~keep]).all()


def test_rows_carry_runner_and_scalar_setting_columns_in_trial_order(tmp_path):
    rows = sweep(tmp_path, trials=2).rows
    assert list(rows.columns[:6]) == [
        "setting_index",
        "trial_index",
        "scale",
        "label",
        "rows",
        "fail_every",
    ]
    assert "methods" not in rows.columns  # a list, not a scalar
    first = rows[(rows["setting_index"] == 1) & (rows["trial_index"] == 1)]
    assert list(first["method"]) == ["a"] * 3 + ["b"] * 3
    assert list(first["epoch"]) == [0, 1, 2] * 2
    assert set(first["label"]) == {"scale-2"}


def test_interrupted_sweep_resumes_without_recomputing_finished_trials(tmp_path, monkeypatch):
    calls_dir = tmp_path / "calls"
    calls_dir.mkdir()
    stop = tmp_path / "stop"
    stop.write_text("interrupt 1 2")  # tasks run trial-major: the 8th of 12
    monkeypatch.setenv("TOY_CALLS_DIR", str(calls_dir))
    monkeypatch.setenv("TOY_STOP_FILE", str(stop))
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        sweep(out, trials=4, chunk_size=2)
    order = [(s, t) for t in range(4) for s in range(3)]
    assert sorted(calls(calls_dir)) == sorted(order[:8])
    stop.unlink()
    for path in calls_dir.iterdir():
        path.unlink()

    result = sweep(out, trials=4, chunk_size=2)

    second = calls(calls_dir)
    assert result.complete and result.n_resumed == 6 and result.n_computed == 6
    assert sorted(second) == sorted(order[6:])  # the chunk with (1, 2) had not finished
    fresh = sweep(tmp_path / "uninterrupted", trials=4)
    assert_frame_equal(result.rows, fresh.rows, check_exact=True)


def test_killed_worker_loses_no_finished_chunk_and_rerun_completes(tmp_path, monkeypatch):
    calls_dir = tmp_path / "calls"
    calls_dir.mkdir()
    stop = tmp_path / "stop"
    stop.write_text("exit 2 3")  # the last of 12 tasks: earlier chunks have finished
    monkeypatch.setenv("TOY_CALLS_DIR", str(calls_dir))
    monkeypatch.setenv("TOY_STOP_FILE", str(stop))
    out = tmp_path / "out"

    broken = sweep(out, trials=4, workers=2, chunk_size=1)

    assert not broken.complete
    assert broken.errors and "BrokenProcessPool" in broken.errors[0]
    assert 0 < broken.n_missing < 12
    finished = {
        (int(s), int(t))
        for s, t in broken.rows[["setting_index", "trial_index"]].drop_duplicates().to_numpy()
    }
    assert len(finished) == 12 - broken.n_missing
    stop.unlink()
    for path in calls_dir.iterdir():
        path.unlink()

    result = sweep(out, trials=4, workers=2, chunk_size=1)

    assert result.complete and result.n_computed == broken.n_missing
    assert not finished & set(calls(calls_dir))
    assert len(result.rows) == 12 * 6


def test_failing_trials_are_recorded_and_the_sweep_goes_on(tmp_path):
    result = sweep(tmp_path, trials=6, overrides={"fail_every": 3, "doomed_setting": 2})

    assert result.complete
    failures = result.failures
    assert len(failures) == result.n_failed == 2 * 2 + 6
    unlucky = failures[failures["error_type"] == "ValueError"]
    assert sorted(unlucky["trial_index"]) == [2, 2, 5, 5]
    assert set(unlucky["message"]) == {"unlucky trial 2", "unlucky trial 5"}
    row = failures[(failures["setting_index"] == 0) & (failures["trial_index"] == 5)].iloc[0]
    assert row["seed"] == "SeedSequence(0, spawn_key=(0, 5))"
    assert "toy_trial" in row["traceback"] and row["scale"] == 1.0
    assert set(result.rows["trial_index"]) == {0, 1, 3, 4}
    summary = result.summary.set_index(["setting_index", "method"], drop=False)
    assert summary.loc[(0, "a"), "failed_trials"] == 2
    doomed = result.summary[result.summary["setting_index"] == 2]
    assert len(doomed) == 1 and doomed["n_rows"].item() == 0
    assert doomed["failed_trials"].item() == 6
    report = (tmp_path / "report.md").read_text()
    assert "10 trials raised" in report and "this setting always fails" in report
    assert len(pd.read_csv(tmp_path / "failures.csv")) == 10

    again = sweep(tmp_path, trials=6, overrides={"fail_every": 3, "doomed_setting": 2})
    assert again.n_computed == 0 and again.n_failed == 10


def test_a_chunk_returns_the_parquet_file_the_store_writes(tmp_path):
    """The worker sends its rows as the Parquet file itself, which reads back as the rows of
    the sweep; the store writes the bytes it receives (their hash in each record)."""
    result = sweep(tmp_path, trials=2)
    specs = [ChunkSpec("c", "tests.sweep_toys:TOY", 0, ((0, 0), (0, 1)), {0: result.settings[0]})]
    (chunk,) = (run_chunk(spec) for spec in specs)
    stored = result.rows[result.rows["setting_index"] == 0].reset_index(drop=True)
    assert isinstance(chunk.rows, bytes) and chunk.n_rows == len(stored) > 0
    read = pq.read_table(pa.BufferReader(chunk.rows)).to_pandas()
    assert_frame_equal(read, stored[read.columns], check_exact=True)
    for path in (tmp_path / "trials").glob("*.json"):  # each record holds its file's hash
        record = json.loads(path.read_text())
        on_disk = (tmp_path / "rows" / f"{record['chunk']}.parquet").read_bytes()
        assert record["rows_sha256"] == hashlib.sha256(on_disk).hexdigest()
    empty = run_chunk(ChunkSpec("e", "tests.sweep_toys:TOY", 0, (), {}))
    assert (empty.rows, empty.n_rows) == (b"", 0)


def test_a_sweep_whose_every_trial_fails_still_writes_its_report(tmp_path):
    """No rows: the experiment's own report (which reads rows) is left out; the generic one
    lists the failures."""
    result = run_sweep(
        TOY_WITH_REPORT, out=tmp_path, trials=2, progress=False, overrides={"fail_every": 1}
    )
    assert result.rows.empty and result.n_failed == len(result.failures) > 0
    report = (tmp_path / "report.md").read_text()
    assert f"{result.n_failed} trials raised" in report and "Toy section" not in report


def test_other_parameters_or_seed_are_refused_unless_fresh(tmp_path):
    sweep(tmp_path, trials=2)
    with pytest.raises(ManifestMismatchError, match=r"seed 0 -> 1.*--fresh"):
        sweep(tmp_path, trials=2, seed=1)
    with pytest.raises(ManifestMismatchError, match="parameter 'rows_per_trial' 3 -> 4"):
        sweep(tmp_path, trials=2, overrides={"rows_per_trial": 4})

    (tmp_path / "manifest.json").unlink()
    with pytest.raises(ManifestMismatchError, match=r"no manifest\.json"):
        sweep(tmp_path, trials=2)

    result = sweep(tmp_path, trials=2, seed=1, fresh=True)

    assert result.n_resumed == 0 and result.n_computed == 6
    assert json.loads((tmp_path / "manifest.json").read_text())["seed"] == 1


def test_more_trials_extend_a_sweep_and_fewer_read_a_subset(tmp_path):
    sweep(tmp_path / "grow", trials=2)
    grown = sweep(tmp_path / "grow", trials=5)
    assert (grown.n_resumed, grown.n_computed) == (6, 9)
    assert_frame_equal(grown.rows, sweep(tmp_path / "direct", trials=5).rows, check_exact=True)

    subset = sweep(tmp_path / "grow", trials=3)
    assert subset.n_computed == 0 and set(subset.rows["trial_index"]) == {0, 1, 2}


def test_chunks_record_the_code_version_and_a_mixed_sweep_says_so(tmp_path):
    """Every chunk record and the manifest carry the code version (this checkout's git
    commit, ``-dirty`` with uncommitted changes); a resumed sweep whose chunks come
    from two versions reports both, with their trial counts, in the result and the
    report."""
    first = sweep(tmp_path, trials=2)
    version = code_version()  # "unknown" outside a git checkout
    assert first.code_versions == {version: 6}
    records = [json.loads(p.read_text()) for p in (tmp_path / "trials").glob("*.json")]
    assert {r["code"] for r in records} == {version}
    assert json.loads((tmp_path / "manifest.json").read_text())["code"] == version
    for path in (tmp_path / "trials").glob("*.json"):  # as if written by older code
        record = json.loads(path.read_text())
        del record["code"]
        path.write_text(json.dumps(record))
    grown = sweep(tmp_path, trials=3)
    assert grown.code_versions == {UNRECORDED: 6, version: 3}
    report = (tmp_path / "report.md").read_text()
    assert f"computed by code versions: `{UNRECORDED}` (6 trials), `{version}` (3 trials)" in (
        report
    )


def test_quick_uses_quick_parameters_and_trials(tmp_path):
    result = sweep(tmp_path, quick=True)
    assert result.trials == TOY.quick_trials
    assert [s["scale"] for s in result.settings] == [1.0]


def test_large_trials_as_frames_or_dicts_give_the_same_rows(tmp_path):
    options = {"methods": ["m1", "m2", "m3", "m4", "m5", "m6"], "rows_per_trial": 6000}
    frames = sweep(tmp_path / "frames", trials=2, overrides={**options, "as_frame": True})
    dicts = sweep(tmp_path / "dicts", trials=2, overrides=options)
    assert len(frames.rows) == 3 * 2 * 36_000
    assert_frame_equal(
        frames.rows.drop(columns="as_frame"), dicts.rows.drop(columns="as_frame"), check_exact=True
    )


def test_outputs_written_to_the_directory(tmp_path):
    result = sweep(tmp_path, trials=3)
    names = {p.name for p in tmp_path.iterdir()}
    assert {"manifest.json", "summary.csv", "failures.csv", "report.md", "rows", "trials"} <= names
    assert list((tmp_path / "rows").glob("*.parquet"))
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["experiment"] == "toy" and manifest["trials"] == 3
    assert manifest["reference"] == "tests.sweep_toys:TOY"
    summary = pd.read_csv(tmp_path / "summary.csv")
    assert len(summary) == len(result.summary) == 3 * 2
    report = (tmp_path / "report.md").read_text()
    assert "attopt run tests.sweep_toys:TOY --trials 3 --seed 0" in report
    invalid_a = int((~result.rows["valid"] & (result.rows["method"] == "a")).sum())
    assert invalid_a > 0 and f"| a | outlier | {invalid_a} |" in report
    # no report of its own: the generic one has the integrity section, per varying setting
    integrity = table(report, "Integrity")
    assert list(integrity.columns[:3]) == ["scale", "label", "method"]
    toy = result.rows[(result.rows["scale"] == 2.0) & (result.rows["method"] == "b")]
    line = row(integrity, {"scale": "2", "method": "b"})
    assert line["epochs"] == str(len(toy)) and line["valid"] == f"{toy['valid'].mean():.3f}"
    assert line["mean NEES"] == "n/a"  # the toy rows carry no NEES


def test_noop_experiment_runs_on_the_process_pool(tmp_path):
    result = run_sweep(NOOP, trials=5, workers=2, out=tmp_path, progress=False)
    assert result.complete and len(result.rows) == 4 * 5
    assert result.summary["n_valid"].tolist() == [5] * 4


def test_dask_engine_uses_an_existing_scheduler_at_an_address(tmp_path):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        address = cluster.scheduler_address
        result = sweep(tmp_path / "remote", trials=2, engine="dask", address=address, workers=None)
        unknown = ChunkSpec("c", "no_such_module:EXPERIMENT", 0, ((0, 0),), {0: {}})
        with DaskEngine(None, address) as engine, pytest.raises(EngineSetupError, match="import"):
            list(engine.run([unknown]))
    assert result.complete
    assert_frame_equal(result.rows, sweep(tmp_path / "serial", trials=2).rows, check_exact=True)


def test_experiment_report_follows_the_generic_report(tmp_path):
    result = run_sweep(TOY_WITH_REPORT, trials=2, workers=1, out=tmp_path, progress=False)
    report = (tmp_path / "report.md").read_text()
    generic, _, own = report.partition("## Toy section")
    assert "# toy-report" in generic and "## Failed trials" in generic
    assert "## Integrity" not in generic  # the experiment's report has its own
    assert f"{len(result.rows)} rows, 6 summary rows, scales [1.0, 2.0, 3.0]." in own
    assert (tmp_path / "toy-figure.txt").read_text() == f"{len(result.rows)} rows\n"


def test_pool_workers_have_one_blas_thread_leave_ctrl_c_and_find_their_loops_compiled(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("OMP_NUM_THREADS", "8")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))  # the workers' cache, empty
    handler = signal.getsignal(signal.SIGINT)
    rows = run_sweep(PROBE, workers=2, out=tmp_path / "out", progress=False, chunk_size=1).rows
    assert len(rows) == 4 and os.getpid() not in set(rows["pid"])
    assert set(rows["omp_threads"]) == {"1"} and rows["ignores_sigint"].all()
    assert rows["loop_ready"].all()  # compiled by one worker before the first trial
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-dask"))
    dask = run_sweep(PROBE, engine="dask", workers=2, out=tmp_path / "dask", progress=False)
    assert dask.rows["loop_ready"].all()
    assert os.environ["OMP_NUM_THREADS"] == "8" and signal.getsignal(signal.SIGINT) is handler


def test_trial_index_recovers_the_trial_of_its_seed() -> None:
    """``trial_index`` inverts ``trial_seed``'s trial number; a bare seed is trial 0."""
    assert [trial_index(trial_seed(5, 3, j)) for j in (0, 1, 17)] == [0, 1, 17]
    assert trial_index(np.random.SeedSequence(7)) == 0
