"""End to end: the adsb-snr experiment (Liu et al. 2023 sec. 5) through the sweep runner."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.adsb_snr.experiment import (
    EXPERIMENT,
    NO_GYRO,
    AdsbSnrParameters,
    epoch_statistics,
    noise_free_pass,
    simulate_pass,
    summary_columns,
)
from attopt.experiments.sweep import run_sweep
from attopt.solvers.snr.fit import fit_at
from tests.report_tables import row, table

SHORT = {"duration_s": 120.0}
"""Two minutes of the pass: 157-193 received messages per epoch, at least 3 per antenna."""
ISSUE_COLUMNS = (
    "method",
    "yaw_max_deg",
    "pitch_max_deg",
    "roll_max_deg",
    "yaw_rms_deg",
    "pitch_rms_deg",
    "roll_rms_deg",
    "runtime_s",
    "valid_fraction",
    "crlb_ratio",
)

PARAMETERS = EXPERIMENT.parameters


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("adsb")
    return run_sweep(EXPERIMENT, trials=1, out=out, workers=1, progress=False, overrides=SHORT)


def _setting() -> dict:
    return {**PARAMETERS, **SHORT}


def _single_frame(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[frame["gyro"] == NO_GYRO]


def test_summary_has_the_issue_columns_for_every_method(sweep):
    summary = pd.read_csv(sweep.out_dir / "summary.csv")
    assert set(ISSUE_COLUMNS) <= set(summary.columns)
    assert set(_single_frame(summary)["method"]) == set(PARAMETERS["methods"])
    filters = summary[summary["gyro"] != NO_GYRO]
    assert set(zip(filters["method"], filters["gyro"], strict=True)) == {
        (m, g) for m in PARAMETERS["filters"] for g in PARAMETERS["gyros"]
    }
    assert np.isfinite(summary[list(ISSUE_COLUMNS[1:])].to_numpy(dtype=float)).all()
    assert (summary["runtime_s"] > 0).all()
    assert (summary["valid_fraction"] > 0.9).all()


def test_nlp_and_nlse_agree_epoch_by_epoch(sweep):
    """Both minimise eq. 19: the same epochs valid, the same estimates.  The first three
    epochs are flagged by both: a second minimum about 50 deg away fits them as well
    (``ambiguous``, 2 dL = 1.5-4.4), and the epochs started without a prior are checked
    for one."""
    rows = sweep.rows[sweep.rows["valid"]]
    nlp = rows[rows["method"] == "nlp"].set_index("t_s")
    nlse = rows[rows["method"] == "nlse"].set_index("t_s")
    assert nlp.index.equals(nlse.index) and len(nlp) == int(SHORT["duration_s"]) - 3
    flagged = sweep.rows[(sweep.rows["method"] == "nlp") & ~sweep.rows["valid"]]
    assert flagged["reason"].str.startswith("ambiguous").all()
    for axis in "xyz":
        # Both minimise eq. 19; LM stops on its loss tolerance within ~1e-6 deg of IPOPT.
        np.testing.assert_allclose(nlp[f"err_{axis}_deg"], nlse[f"err_{axis}_deg"], atol=1e-4)


def test_nlp_is_efficient_on_the_short_pass(sweep):
    summary = sweep.summary.set_index("method")
    ratio = summary.loc["nlp", "crlb_ratio"]
    # 120 independent epochs: the report's standard error of the ratio is ~0.05 here, so
    # 0.7 is 6 standard errors below 1; above 1 the band also holds the reception-threshold
    # bias, which raised the ratio to ~1.35 for 100-199 messages over the whole hour.
    assert 0.7 < ratio < 1.5
    assert summary.loc["nlp", "crlb_ratio_10plus"] == ratio  # every epoch has >= 10 here


def test_truncated_ml_nlp_reaches_the_truncated_bound_on_the_short_pass(sweep):
    summary = sweep.summary.set_index("method")
    ratio = summary.loc["nlp_truncated", "crlb_ratio_truncated"]
    # Measured 0.94 here; with 120 epochs the standard error of the ratio is ~0.05, so
    # the band is 5 standard errors either side of 1.  (Whether it beats the NLP here is not
    # tested: on these dense epochs the selection bias is small, 0.93 vs 0.94 for trial 0.)
    assert 0.75 < ratio < 1.25
    rows = sweep.rows[(sweep.rows["method"] == "nlp_truncated") & sweep.rows["valid"]]
    # Mean NEES of 120 epochs: chi^2_3 has variance 6, standard error ~0.22; measured 2.75.
    assert 2.0 < rows["nees"].mean() < 4.0


def test_report_table_by_observation_count_shows_each_method_against_each_bound(sweep):
    # Every epoch of the short pass has 100-199 messages: one bin, equal to the summary.
    report = (sweep.out_dir / "report.md").read_text()
    bins = table(
        report, "Accuracy against the number of received observations (Liu et al. 2023 Fig. 10)"
    )
    cells = row(bins, {"received observations": "100-199"})
    summary = sweep.summary.set_index("method")
    for method in ("nlp", "nlp_truncated"):
        for column, label in (
            ("crlb_ratio", "RMS / CRLB"),
            ("crlb_ratio_truncated", "RMS / truncated CRLB"),
        ):
            assert float(cells[f"{method} {label}"]) == pytest.approx(
                summary.loc[method, column], abs=5e-4
            )


def test_report_tables_recompute_from_the_rows(sweep):
    """Table 2's Euler-difference RMS, the efficiency table and the integrity section
    against the same statistics computed here from the stored rows."""
    report = (sweep.out_dir / "report.md").read_text()
    rows = sweep.rows[sweep.rows["valid"]]
    nlp = rows[(rows["method"] == "nlp") & (rows["gyro"] == NO_GYRO)]
    euler = row(
        table(report, "Liu et al. 2023 Table 2 beside ours"), {"row": "nlp", "errors": "Euler"}
    )
    expected = [np.sqrt(np.mean(nlp[f"euler_{n}_err_deg"] ** 2)) for n in ("yaw", "pitch", "roll")]
    assert euler["RMS yaw / pitch / roll (deg)"] == " / ".join(f"{v:.2f}" for v in expected)
    nlse = row(table(report, "Efficiency"), {"method": "nlse"})
    gap = float(nlse["largest difference from nlp (deg)"])
    assert 0.0 < gap < 1e-4  # the two minimise eq. 19 (test_nlp_and_nlse_agree_epoch_by_epoch)
    integrity = row(table(report, "Integrity"), {"gyro": "mems", "method": "mekf_snr"})
    filtered = rows[(rows["method"] == "mekf_snr") & (rows["gyro"] == "mems")]
    assert integrity["valid epochs with a NEES"] == str(len(filtered))
    assert float(integrity["share beyond 21.1"]) == pytest.approx(
        np.mean(filtered["nees"] > 21.107), abs=5e-4
    )
    assert float(integrity["mean NEES"]) == pytest.approx(filtered["nees"].mean(), rel=5e-3)


def test_wrong_minima_are_checked_on_every_20th_epoch(sweep):
    rows = _single_frame(sweep.rows)
    checked = rows.dropna(subset=["wrong_minimum"])
    every_20th = set(np.arange(0.0, SHORT["duration_s"], 20.0))
    assert every_20th - {0.0} <= set(checked["t_s"]) <= every_20th  # epoch 0: ambiguous
    assert set(checked["wrong_minimum"]) <= {0.0, 1.0}
    summary = _single_frame(sweep.summary).set_index("method")
    # every valid 20th epoch; the two-step method flags one of them (a second boresight)
    valid_checked = checked[checked["valid"]].groupby("method").size()
    assert (summary["wrong_minimum_checked"] == valid_checked[summary.index]).all()
    # the one-step methods flag epoch 0 as ambiguous: the other five are checked
    assert (summary["wrong_minimum_checked"].drop("deterministic") == 5).all()
    filters = sweep.summary[sweep.summary["gyro"] != NO_GYRO]
    assert (filters["wrong_minimum_checked"] == 0).all()


def test_report_has_table_2_and_existing_figures(sweep):
    report = (sweep.out_dir / "report.md").read_text()
    assert "## Liu et al. 2023 Table 2 beside ours" in report
    assert "-25.33 / -18.78 / -28.68" in report  # QUEST maximum
    assert "1.21 / 0.85 / 1.48" in report  # NLSE RMS
    assert "1.46 / -1.31 / 2.40" in report  # the paper's MEKF maximum
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    expected = {"observations.png", "error_vs_observations.png"}
    expected |= {f"error_{m}.png" for m in PARAMETERS["methods"]}
    expected |= {
        f"{k}_{g}.png" for k in ("filter_errors", "gyro_bias") for g in PARAMETERS["gyros"]
    }
    assert set(links) == expected
    for name in links:
        assert (sweep.out_dir / name).stat().st_size > 10_000


def test_a_trial_replays_bitwise_with_any_subset_of_its_methods(sweep):
    """Two single-frame methods and two filters (the paper's MEKF reads the NLSE's
    track) replay the sweep's rows bit for bit, runtime aside: a method's rows do not
    depend on which others run beside it."""
    subset = {"methods": ["deterministic", "nlse"], "filters": ["mekf_paper", "mekf_snr"]}
    replay = EXPERIMENT.trial({**_setting(), **subset}, np.random.SeedSequence(0, spawn_key=(0, 0)))
    assert set(replay["method"]) == {*subset["methods"], *subset["filters"]}
    stored = sweep.rows[sweep.rows["method"].isin(replay["method"])]
    stored = stored[replay.columns].reset_index(drop=True)
    columns = [c for c in replay.columns if c != "runtime_s"]
    pd.testing.assert_frame_equal(replay[columns], stored[columns], check_dtype=False)


@pytest.mark.parametrize(
    ("objective", "prefix"), [("least_squares", "bound_"), ("truncated_ml", "bound_truncated_")]
)
def test_crb_at_the_truth_matches_the_solvers_covariance_formula(objective, prefix):
    # The experiment's bounds and the solvers' covariances share one definition
    # (eq. 22; formulations/snr_truncation.py for the truncated model, whose tests
    # check it against scipy's truncnorm).
    scenario = noise_free_pass(AdsbSnrParameters.model_validate(_setting()))
    noisy = simulate_pass(scenario, np.random.default_rng(1), 1.0, 6.0)
    columns = epoch_statistics(scenario, noisy, 1.0, 6.0)
    for k in (0, 37, 119):
        covariance = fit_at(noisy.epochs[k], scenario.truth[k], objective).covariance
        expected = np.degrees(np.sqrt(np.diag(covariance)))
        got = [columns[f"{prefix}{a}_deg"][k] for a in "xyz"]
        np.testing.assert_allclose(got, expected, rtol=1e-9)
        assert columns["n_obs"][k] == noisy.epochs[k].m
        untruncated = [columns[f"bound_{a}_deg"][k] for a in "xyz"]
        if objective == "truncated_ml":
            assert np.all(np.asarray(got) > untruncated)  # truncation only removes information


def test_summary_columns_survive_a_method_without_valid_epochs(sweep):
    rows = sweep.rows.copy()
    rows.loc[rows["method"] == "deterministic", "valid"] = False
    summary = summary_columns(rows, ["setting_index", "method"]).set_index("method")
    assert np.isnan(summary.loc["deterministic", ["yaw_max_deg", "crlb_ratio"]]).all()
    assert summary.loc["deterministic", "n_unbounded"] == 0
    assert (
        summary.loc["nlp", "crlb_ratio"]
        == sweep.summary.set_index("method").loc["nlp", "crlb_ratio"]
    )


def _filter_rms(rows: pd.DataFrame, method: str, gyro: str, start_s: float) -> float:
    chosen = rows[(rows["method"] == method) & (rows["gyro"] == gyro) & (rows["t_s"] >= start_s)]
    return float(np.sqrt(sum((chosen[f"err_{a}_deg"] ** 2).mean() for a in "xyz")))


def test_filter_rows_are_valid_and_consistent_for_every_gyro(sweep):
    rows = sweep.rows[sweep.rows["gyro"] != NO_GYRO]
    for (method, gyro), group in rows.groupby(["method", "gyro"]):
        assert len(group) == int(SHORT["duration_s"]), (method, gyro)
        assert group["valid"].all(), (method, gyro)
        settled = group[group["t_s"] >= 60.0]
        # 60 epochs of a 3-dof NEES; generous band (errors are correlated in time);
        # mekf_paper's covariance considers its input's whole one, so it may be far
        # below 3 (measured 0.26 with the MEMS gyro)
        lowest = 0.0 if method == "mekf_paper" else 0.5
        assert lowest < settled["nees"].mean() < 8.0, (method, gyro)
        assert np.isfinite(settled["bias_err_x_deg_h"]).all()


@pytest.mark.parametrize("gyro", PARAMETERS["gyros"])
def test_the_papers_mekf_reports_at_least_its_inputs_covariance(sweep, gyro):
    """``mekf_paper``'s reported covariance considers its input's (the NLSE's errors are
    correlated from epoch to epoch): on every epoch after the NLSE's first valid one its
    variance about each axis is at least the NLSE's most recent."""
    paper = sweep.rows[(sweep.rows["method"] == "mekf_paper") & (sweep.rows["gyro"] == gyro)]
    nlse = sweep.rows[sweep.rows["method"] == "nlse"].sort_values("t_s")
    held = nlse.set_index("t_s").where(nlse.set_index("t_s")["valid"]).ffill()
    paper = paper.set_index("t_s").loc[held.index]
    after = held["valid"].notna().to_numpy()
    for axis in "xyz":
        column = f"sigma_{axis}_deg"
        assert (paper[column].to_numpy()[after] >= held[column].to_numpy()[after]).all()


@pytest.mark.parametrize("gyro", PARAMETERS["gyros"])
def test_snr_filters_beat_the_papers_mekf(sweep, gyro):
    # The issue's target is "at most half" over the hour (the report measures it);
    # on the first two minutes, still settling from the 10 deg initial error, the
    # ratio measured 0.86 with the liu2023 gyro and 0.72 with the MEMS one.
    paper = _filter_rms(sweep.rows, "mekf_paper", gyro, 60.0)
    for method in ("mekf_snr", "usque_snr", "rts_snr"):
        assert _filter_rms(sweep.rows, method, gyro, 60.0) < paper, method
    assert _filter_rms(sweep.rows, "rts_snr", gyro, 0.0) < _filter_rms(
        sweep.rows, "mekf_snr", gyro, 0.0
    )


@pytest.mark.parametrize("gyro", PARAMETERS["gyros"])
def test_factor_graph_rows_beat_the_filters_and_carry_the_posterior_bound(sweep, gyro):
    """The batch smoother (started from the online one) is at least as good as the
    online one and the RTS pass; the online one is as good as the MEKF; every
    gyro-aided row carries the same finite posterior bound, below the batch RMS
    of this short settling pass at most by the margin of one trial."""
    rows = sweep.rows[sweep.rows["gyro"] == gyro]
    batch = _filter_rms(rows, "fg_batch", gyro, 0.0)
    assert batch <= 1.02 * _filter_rms(rows, "fg_online", gyro, 0.0)
    # both approximate the same MAP estimate; one trial's RMS differs either way
    # (measured 0.364 against 0.346 deg with the liu2023 gyro)
    assert batch <= 1.1 * _filter_rms(rows, "rts_snr", gyro, 0.0)
    assert _filter_rms(rows, "fg_online", gyro, 0.0) < 1.1 * _filter_rms(
        rows, "mekf_snr", gyro, 0.0
    )
    bound = rows[[f"pbound_{a}_deg" for a in "xyz"]].to_numpy()
    assert np.isfinite(bound).all() and (bound > 0).all()
    per_method = rows.groupby("method")["pbound_x_deg"].apply(lambda b: b.to_numpy())
    for method in per_method.index:
        np.testing.assert_array_equal(per_method[method], per_method["fg_batch"])
    settled = rows[(rows["method"] == "fg_batch") & (rows["t_s"] >= 60.0)]
    ratio = _filter_rms(settled, "fg_batch", gyro, 60.0) / np.sqrt(
        sum((settled[f"pbound_{a}_deg"] ** 2).mean() for a in "xyz")
    )
    assert 0.5 < ratio < 2.0


def test_power_offsets_modelled_by_the_smoother():
    """Aircraft power offsets of 2 dB on a short pass: the smoother that estimates one
    offset per aircraft is far better than the one that does not (300 s: docs/results.md),
    the latter's residual test off to see its errors (it
    flags every epoch: test_unmodelled_power_offsets_are_flagged).  The one that models
    them is valid throughout and consistent, and its rows carry the posterior bound with
    the powers unknown, looser than the plain smoother's."""
    setting = {
        **PARAMETERS,
        "duration_s": 90.0,
        "methods": [],
        "filters": ["fg_batch", "fg_batch_offsets"],
        "gyros": ["mems"],
        "traffic": {"power_offset_sigma_db": 2.0},
        "estimator_options": {"fg_batch": {"filter": {"consistency_window": 0}}},
    }
    rows = EXPERIMENT.trial(EXPERIMENT.grid(setting)[0], np.random.SeedSequence(3))
    assert rows["valid"].all()
    modelled_rows = rows[rows["method"] == "fg_batch_offsets"]
    assert modelled_rows["nees"].mean() < 3.0
    plain = _filter_rms(rows, "fg_batch", "mems", 30.0)
    modelled = _filter_rms(rows, "fg_batch_offsets", "mems", 30.0)
    assert modelled < 0.5 * plain
    bound = rows.groupby("method")[["pbound_x_deg", "pbound_y_deg", "pbound_z_deg"]].mean()
    assert (bound.loc["fg_batch_offsets"] > bound.loc["fg_batch"]).all()  # the powers unknown


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"filters": ["ekf"]}, "unknown filters"),
        ({"gyros": ["fog"]}, r"gyros\[0\] = .fog."),
        ({"filter_snr_model": "laplace"}, "filter_snr_model"),
    ],
)
def test_unknown_filter_settings_are_rejected(tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        run_sweep(EXPERIMENT, trials=1, out=tmp_path, workers=1, progress=False, overrides=override)


def test_unknown_method_is_rejected(tmp_path):
    with pytest.raises(ValueError, match=r"unknown methods \['mekf'\]"):
        run_sweep(
            EXPERIMENT,
            trials=1,
            out=tmp_path,
            workers=1,
            progress=False,
            overrides={**SHORT, "methods": ["nlp", "mekf"]},
        )
