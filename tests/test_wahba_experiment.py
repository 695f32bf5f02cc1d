"""End to end: the wahba-mag-sun experiment through the sweep runner, and its benchmark."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.benchmarks.wahba import run as run_bench
from attopt.experiments.config import ConfigError, resolve_parameters
from attopt.experiments.registry import get_experiment
from attopt.experiments.reporting.statistics import nees_threshold
from attopt.experiments.sweep import run_sweep
from attopt.experiments.wahba_mag_sun.experiment import EXPERIMENT, geometry_of
from attopt.experiments.wahba_mag_sun.scenario import interval_labels
from tests.report_tables import row, table

FILTERS = ["mekf", "usque", "rts", "fg_batch"]
SHORT = {
    "duration_s": 1300.0,
    "methods": ["triad", "q_method", "quest", "sdp"],
    "filters": FILTERS,
}
"""1300 s: the eclipse starts at 1001 s, so the last 299 epochs are in it."""
SETTLED_S = 120.0
"""The filters converge from the 10 deg initial error well within this time."""

PARAMETERS = EXPERIMENT.parameters


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
    assert set(summary["method"]) == set(SHORT["methods"]) | set(FILTERS)


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
    by_method = {m: g.sort_values(["trial_index", "t_s"]) for m, g in rows.groupby("method")}
    for method in ("quest", "sdp"):
        np.testing.assert_allclose(
            by_method[method]["err_x_deg"].to_numpy(),
            by_method["q_method"]["err_x_deg"].to_numpy(),
            atol=1e-6,
        )


def test_report_puts_table_1_beside_the_summary(sweep):
    report = (sweep.out_dir / "report.md").read_text()
    table1 = table(report, "Cilden Guler et al. 2017 Table 1 beside ours")
    q_method = row(table1, {"method": "q_method", "interval": "before_eclipse"})
    assert q_method["RMS roll / pitch / yaw (Cilden Guler et al. 2017 Table 1)"] == (
        "3.38 / 1.79 / 0.97"
    )
    summary = sweep.summary.set_index(["method", "interval"]).loc[("q_method", "before_eclipse")]
    ours = " / ".join(f"{summary[f'{a}_rms_deg']:.3f}" for a in ("roll", "pitch", "yaw"))
    assert q_method["RMS roll / pitch / yaw"] == ours
    assert row(table1, {"method": "triad", "interval": "eclipse"}).iloc[3:6].tolist() == [
        "-",
        "-",
        "nd",
    ]
    assert (sweep.out_dir / "error_quest.png").stat().st_size > 10_000


def test_filters_carry_the_attitude_through_the_eclipse(sweep):
    summary = sweep.summary.set_index(["method", "interval"])
    rows = sweep.rows[sweep.rows["method"].isin(FILTERS) & (sweep.rows["t_s"] >= SETTLED_S)]
    for method, frame in rows.groupby("method"):
        assert summary.loc[(method, "eclipse"), "valid_fraction"] == 1.0
        assert summary.loc[(method, "before_eclipse"), "valid_fraction"] == 1.0
        errors = frame[["err_x_deg", "err_y_deg", "err_z_deg"]].to_numpy()
        assert np.isfinite(errors).all()
        # MEMS gyro: about 0.1 deg before the eclipse, growing to a few tenths in 300 s of it.
        assert np.abs(errors).max() < 1.0, method
        assert summary.loc[(method, "before_eclipse"), "total_rms_deg"] < 0.2, method
        for interval, group in frame.groupby("interval"):
            # 3 when consistent; 2 trials of strongly correlated epochs, so only "not absurd".
            assert 1.0 < group["nees"].mean() < 10.0, (method, interval)
            assert 2.0 < group["nees_full"].mean() < 20.0, (method, interval)
        assert np.isfinite(frame["runtime_s"]).all() and (frame["runtime_s"] > 0).all()
    # bias estimate minus bias error: the same true bias whichever filter's rows give it
    true_bias = rows.assign(
        **{a: rows[f"bias_{a}_deg_h"] - rows[f"bias_err_{a}_deg_h"] for a in "xyz"}
    ).pivot_table(index=["trial_index", "t_s"], columns="method", values=list("xyz"))
    for axis in "xyz":
        spread = true_bias[axis].max(axis=1) - true_bias[axis].min(axis=1)
        assert spread.max() < 1e-6
    single = sweep.rows[sweep.rows["method"].isin(SHORT["methods"])]
    assert single["runtime_s"].isna().all() and single["nees_full"].isna().all()


LITERAL_GYRO_WINDOW = {"start_utc": "2026-05-10T23:33:00", "duration_s": 900.0}
"""400 s of sunlight and the first 500 s of the eclipse (from 600 s into the default pass)."""


def _literal_gyro_mekf(limit_deg: float | None, window: dict | None = None) -> pd.DataFrame:
    """The MEKF's rows with Liu et al. 2023's gyro read literally, over ``window`` (the
    default pass when ``None``), with an attitude sigma limit of ``limit_deg`` (``None``:
    the default)."""
    options = {} if limit_deg is None else {"max_attitude_sigma": float(np.radians(limit_deg))}
    overrides = {
        **(window or {}),
        "gyro": "liu2023",
        "methods": ["q_method"],
        "filters": ["mekf"],
        "estimator_options": {"mekf": {"filter": options}},
    }
    parameters = resolve_parameters(EXPERIMENT, overrides=overrides)
    (setting,) = EXPERIMENT.grid(parameters.model_dump(mode="json"))
    rows = EXPERIMENT.trial(setting, np.random.SeedSequence(0, spawn_key=(0, 0)))
    return rows[rows["method"] == "mekf"]


def test_the_literal_gyro_through_the_eclipse_is_flagged_and_reacquired():
    """Through the eclipse the gyro alone carries the attitude and its covariance grows;
    beyond ``max_attitude_sigma`` (15 deg) the first-order propagation no longer describes
    the errors: with a limit of 30 deg the MEKF reports eclipse epochs valid up to
    179 deg off (85 of 500 beyond the chi-square(3) 1 - 1e-4 quantile, measured).  With
    the defaults, over the whole pass, the epochs over the limit say why, the share
    beyond the quantile is at most 0.001, and after the eclipse the filter restarts from
    the Sun and field vectors and is valid again within 60 s (measured 30 s; with the
    restart's bias covariance reset to the prior's, which the eclipse had outgrown, 330 s
    of restarts every 10 s)."""
    loose = _literal_gyro_mekf(30.0, LITERAL_GYRO_WINDOW)
    assert (loose["valid"] & (loose["nees"] > nees_threshold())).sum() > 20
    rows = _literal_gyro_mekf(None)
    valid = rows[rows["valid"]]
    assert (valid["nees"] > nees_threshold()).mean() <= 0.001
    eclipse = rows[rows["interval"] == "eclipse"]
    assert not eclipse["valid"].all()
    assert set(eclipse.loc[~eclipse["valid"], "reason"]) == {
        "attitude not determined: 1-sigma above 15 deg"
    }
    after = rows[rows["interval"] == "after_eclipse"]
    assert after.loc[after["t_s"] >= after["t_s"].min() + 60.0, "valid"].all()


def test_factor_graph_smoother_reaches_the_posterior_bound_through_the_eclipse(sweep):
    """``fg_batch`` (vectors + gyro through the eclipse, from the RTS estimates): at
    most the MEKF's RMS, about the RTS pass's (same MAP problem), and near the
    posterior bound of the pass that every gyro-aided row carries."""
    rows = sweep.rows[sweep.rows["method"].isin(FILTERS) & (sweep.rows["t_s"] >= SETTLED_S)]

    def rms(method: str, column: str = "err_{}_deg") -> float:
        chosen = rows[rows["method"] == method]
        return float(np.sqrt(sum((chosen[column.format(a)] ** 2).mean() for a in "xyz")))

    assert rms("fg_batch") < rms("mekf")
    assert abs(rms("fg_batch") / rms("rts") - 1.0) < 0.05
    assert 0.7 < rms("fg_batch") / rms("fg_batch", "pbound_{}_deg") < 1.3
    bounds = rows.pivot_table(index=["trial_index", "t_s"], columns="method", values="pbound_x_deg")
    assert (bounds.max(axis=1) - bounds.min(axis=1)).max() == 0.0


@pytest.fixture(scope="module")
def replay():
    """Trial 0 of the sweep replayed with the RTS filter only, and without filters."""
    setting = EXPERIMENT.grid({**PARAMETERS, **SHORT})[0]
    seed = np.random.SeedSequence(0, spawn_key=(0, 0))
    with_filters = EXPERIMENT.trial({**setting, "filters": ["rts"]}, seed)
    without = EXPERIMENT.trial({**setting, "filters": []}, seed)
    return with_filters, without


def test_filter_rows_replay_identically(sweep, replay):
    """Same seed, same rows (but the wall time), whichever other filters run beside."""
    with_filters, _ = replay
    stored = sweep.rows[sweep.rows["trial_index"] == 0]
    stored = stored[stored["method"].isin(with_filters["method"])]
    stored = stored[list(with_filters.columns)].reset_index(drop=True)
    assert len(stored) == len(with_filters)
    columns = [c for c in with_filters.columns if c != "runtime_s"]
    pd.testing.assert_frame_equal(stored[columns], with_filters[columns], check_dtype=False)


def test_single_frame_rows_do_not_depend_on_the_filters(replay):
    with_filters, without = replay
    assert set(without["method"]) == set(SHORT["methods"])
    assert "runtime_s" not in without.columns
    same = with_filters[with_filters["method"].isin(SHORT["methods"])]
    pd.testing.assert_frame_equal(same[list(without.columns)].reset_index(drop=True), without)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"filters": ["mekf", "ukf"]}, "unknown filters"),
        ({"filters": ["mekf", "mekf"]}, "unique"),
        ({"gyro": "fog"}, "'fog': Input should be 'liu2023' or 'mems'"),
        ({"initial_sigma_deg": 0.0}, "initial_sigma_deg"),
    ],
)
def test_bad_filter_parameters_are_rejected(overrides, message):
    with pytest.raises(ConfigError, match=message):
        resolve_parameters(EXPERIMENT, overrides=overrides)


def test_report_has_the_filter_section_and_integrity(sweep):
    report = (sweep.out_dir / "report.md").read_text()
    filters = table(report, "Gyro-aided filters through the eclipse")
    rows = sweep.rows[sweep.rows["method"].isin(FILTERS) & (sweep.rows["interval"] == "eclipse")]
    for method, frame in rows.groupby("method"):
        line = row(filters, {"method": method, "interval": "eclipse"})
        assert line["mean NEES (3)"] == f"{frame['nees'].mean():.3f}"
        assert line["mean NEES (6)"] == f"{frame['nees_full'].mean():.3f}"
        ratio = np.sqrt(
            sum((frame[f"err_{a}_deg"] ** 2).mean() for a in "xyz")
            / sum((frame[f"pbound_{a}_deg"] ** 2).mean() for a in "xyz")
        )
        assert float(line["RMS / posterior bound"]) == pytest.approx(ratio, abs=5e-4)
    runtime = table(report, "Gyro-aided filters through the eclipse", 1)
    assert runtime["filter"].tolist() == FILTERS and set(runtime["passes"]) == {"2"}
    integrity = table(report, "Integrity")
    sdp = row(integrity, {"method": "sdp", "interval": "eclipse"})
    assert sdp.iloc[2:].tolist() == ["598", "0.000", "0", "n/a", "n/a"]  # 2 x 299 epochs
    valid = sweep.rows[(sweep.rows["method"] == "sdp") & (sweep.rows["interval"] != "eclipse")]
    line = row(integrity, {"method": "sdp", "interval": "before_eclipse"})
    assert float(line["mean NEES"]) == pytest.approx(valid["nees"].mean(), rel=5e-3)
    for name in ("filter_errors.png", "gyro_bias.png"):
        assert f"![{name}]({name})" in report
        assert (sweep.out_dir / name).stat().st_size > 10_000
    assert not (sweep.out_dir / "error_mekf.png").exists()


def test_intervals_follow_the_computed_eclipse():
    geometry = geometry_of(resolve_parameters(EXPERIMENT))
    labels = interval_labels(geometry)
    ((start, end),) = geometry.eclipses
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
    rows = run_bench(n_batch=300, calls=40)  # the answers; speed is measured by the benchmark
    assert {r.method for r in rows} >= {"q_method", "quest", "svd", "foam", "sdp", "triad"}
    for r in rows:
        if r.method not in ("triad", "triad (numpy)", "align_vectors (scipy)"):
            assert r.max_diff_rad < 1e-9, r
