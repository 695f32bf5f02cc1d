"""End to end: the wahba-mag-sun experiment through the sweep runner, and its benchmark."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from experiments.bench_wahba import run as run_bench
from experiments.registry import get_experiment
from experiments.scenarios.wahba_mag_sun import build_geometry
from experiments.sweep import run_sweep
from experiments.wahba_mag_sun import EXPERIMENT, interval_labels

SHORT = {"duration_s": 1300.0, "methods": ["triad", "q_method", "quest", "sdp"]}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("wahba")
    return run_sweep(EXPERIMENT, trials=2, out=out, workers=1, progress=False, overrides=SHORT)


def test_registered():
    assert get_experiment("wahba-mag-sun") is EXPERIMENT


def test_summary_has_the_issue_columns(sweep):
    summary = pd.read_csv(sweep.out_dir / "summary.csv")
    for column in (
        "method",
        "interval",
        "roll_rms_deg",
        "pitch_rms_deg",
        "yaw_rms_deg",
        "valid_fraction",
    ):
        assert column in summary.columns
    assert set(summary["interval"]) == {"before_eclipse", "eclipse"}
    assert set(summary["method"]) == set(SHORT["methods"])


def test_eclipse_is_unobservable_and_sunlit_is_efficient(sweep):
    summary = sweep.summary.set_index(["method", "interval"])
    for method in SHORT["methods"]:
        assert summary.loc[(method, "eclipse"), "valid_fraction"] == 0.0
        sunlit = summary.loc[(method, "before_eclipse")]
        assert sunlit["valid_fraction"] == 1.0
        for axis in ("roll", "pitch", "yaw"):
            # 2 x 1001 epochs: the RMS/CRB ratio of an efficient estimator is 1 +/- ~3%.
            assert 0.9 < sunlit[f"{axis}_ratio"] < 1.1


def test_optimal_methods_give_identical_errors(sweep):
    rows = sweep.rows[sweep.rows["valid"]]
    by_method = {m: g.sort_values(["trial_index", "t"]) for m, g in rows.groupby("method")}
    for method in ("quest", "sdp"):
        np.testing.assert_allclose(
            by_method[method]["err_x_deg"].to_numpy(),
            by_method["q_method"]["err_x_deg"].to_numpy(),
            atol=1e-6,
        )


def test_report_compares_with_seed_002(sweep):
    report = (sweep.out_dir / "report.md").read_text()
    assert "Seed 002 Table 1 beside ours" in report
    assert "3.38 / 1.79 / 0.97" in report  # the seed's q-method row, before eclipse
    assert (sweep.out_dir / "error_quest.png").stat().st_size > 10_000


def test_intervals_follow_the_computed_eclipse():
    geometry = build_geometry(6000.0, 1.0)
    labels = interval_labels(geometry)
    start, end = geometry.eclipse_interval
    assert (labels[geometry.in_eclipse] == "eclipse").all()
    assert (labels[geometry.t < start] == "before_eclipse").all()
    assert (labels[geometry.t >= end] == "after_eclipse").all()


def test_unknown_method_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="unknown methods"):
        run_sweep(
            EXPERIMENT,
            trials=1,
            out=tmp_path,
            workers=1,
            progress=False,
            overrides={"methods": ["q_method", "davenport"]},
        )


def test_benchmark_answers_agree_with_align_vectors():
    rows = run_bench(n_batch=2000, calls=100)
    assert {r.method for r in rows} >= {"q_method", "quest", "svd", "foam", "sdp", "triad"}
    for r in rows:
        if r.method not in ("triad", "align_vectors (scipy)"):
            assert r.max_diff_rad < 1e-9, r
