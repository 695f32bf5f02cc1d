"""The reports' shared helpers: statistics (the integrity statistic above all), tables,
paper values and the one plotting routine."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.experiments.reporting.figures import error_figure
from attopt.experiments.reporting.integrity import integrity_section, worst_share
from attopt.experiments.reporting.paper_values import paper_label, paper_table, paper_values
from attopt.experiments.reporting.statistics import (
    INTEGRITY_PROBABILITY,
    flagged_by_reason,
    inside_3_sigma,
    integrity,
    nees_interval,
    nees_threshold,
    rms,
    rms_ratio,
    rms_ratio_standard_error,
    run_averaged_nees,
    signed_max,
)
from attopt.experiments.reporting.tables import joined, markdown_table, with_paper
from attopt.solvers.plotting import plot_axes
from attopt.solvers.results import Track
from tests.report_tables import row, table

PAPERS = {
    "attopt.experiments.wahba_mag_sun": "Cilden Guler et al. 2017",
    "attopt.experiments.adsb_snr": "Liu et al. 2023",
    "attopt.experiments.doa_ground": "Yang et al. 2014",
    "attopt.experiments.geo_snr_stations": "Pimienta-Penalver and Crassidis",
}


def _track_rows(n: int, sigma_scale: float, seed: int, method: str) -> pd.DataFrame:
    """Rows of ``n`` epochs whose errors are drawn from random covariances ``P``; the track
    reports ``(sigma_scale)^2 P`` (1: consistent; below 1: overconfident)."""
    rng = np.random.default_rng(seed)
    factor = 1e-3 * rng.normal(size=(n, 3, 3))
    covariance = factor @ factor.transpose(0, 2, 1) + 1e-8 * np.eye(3)
    error = np.einsum("nij,nj->ni", np.linalg.cholesky(covariance), rng.normal(size=(n, 3)))
    truth = Rotation.random(n, random_state=seed)
    track = Track(
        method=method,
        quaternion=(Rotation.from_rotvec(error) * truth).as_quat(),
        covariance=sigma_scale**2 * covariance,
        loss=np.zeros(n),
        valid=np.ones(n, dtype=bool),
        reason=np.full(n, "", dtype=object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
    )
    return track.to_dataframe(truth).assign(method=method)


def test_integrity_of_a_consistent_and_an_overconfident_estimator():
    """Errors drawn from the reported covariance exceed the chi-square(3) 1 - 1e-4 quantile
    at about 1e-4 of the epochs; a covariance claiming half the sigma (NEES x 4) exceeds it
    at P(chi2_3 > 21.1 / 4) = 0.15."""
    n = 200_000
    rows = pd.concat(
        [_track_rows(n, 1.0, 1, "consistent"), _track_rows(20_000, 0.5, 2, "overconfident")]
    )
    result = integrity(rows, ["method"])
    consistent = result.loc["consistent"]
    # 20 expected exceedances (Poisson sd 4.5): 10-40 is more than four sd either side.
    assert 10 / n < consistent["share_beyond"] < 40 / n
    assert consistent["mean_nees"] == pytest.approx(3.0, abs=0.03)  # sd of the mean 0.0055
    assert (consistent["epochs"], consistent["nees_epochs"]) == (n, n)
    overconfident = result.loc["overconfident"]
    expected = chi2.sf(nees_threshold() / 4.0, 3)
    assert overconfident["share_beyond"] == pytest.approx(expected, abs=0.02)
    assert overconfident["mean_nees"] == pytest.approx(12.0, rel=0.05)
    assert nees_threshold() == pytest.approx(chi2.ppf(1 - INTEGRITY_PROBABILITY, 3))


def test_integrity_counts_only_valid_epochs_and_shows_no_nees_as_missing():
    rows = pd.DataFrame(
        {
            "method": ["a"] * 4 + ["b"] * 2,
            "err_x_deg": [0.1, 0.1, 0.1, np.nan, 0.1, 0.1],
            "err_y_deg": 0.0,
            "err_z_deg": 0.0,
            "valid": [True, True, False, False, True, True],
            "nees": [1.0, 30.0, 1e6, np.nan, np.nan, np.nan],
        }
    )
    result = integrity(rows, ["method"])
    assert result.loc["a"].tolist() == [4, 0.5, 2, 0.5, 15.5]
    assert result.loc["b", "nees_epochs"] == 0 and result.loc["b", "valid_fraction"] == 1.0
    assert np.isnan(result.loc["b", "share_beyond"]) and np.isnan(result.loc["b", "mean_nees"])
    without = integrity(rows.drop(columns="nees"), ["method"])
    assert without["mean_nees"].isna().all() and (without["nees_epochs"] == 0).all()
    text = integrity_section(rows, ["method"], "attopt run x")
    section = table(text, "Integrity")
    assert row(section, {"method": "b"})["mean NEES"] == "n/a"
    assert row(section, {"method": "a"})["share beyond 21.1"] == "0.5"
    assert "From `attopt run x`." in text


@given(
    st.lists(
        st.tuples(
            st.sampled_from("pq"),
            st.booleans(),
            st.one_of(st.just(float("nan")), st.floats(0.0, 100.0)),
        ),
        min_size=1,
        max_size=40,
    )
)
def test_integrity_share_is_the_count_beyond_the_quantile(entries):
    method, valid, nees = zip(*entries, strict=True)
    rows = pd.DataFrame({"method": method, "valid": valid, "nees": nees, "err_x_deg": 0.0}).assign(
        err_y_deg=0.0, err_z_deg=0.0
    )
    result = integrity(rows, ["method"])
    for name, group in rows.groupby("method"):
        judged = group.loc[group["valid"] & group["nees"].notna(), "nees"]
        assert result.loc[name, "nees_epochs"] == len(judged)
        share = result.loc[name, "share_beyond"]
        if len(judged):
            assert share == np.mean(judged > nees_threshold())
        else:
            assert np.isnan(share)


@given(
    st.lists(
        st.tuples(
            st.sampled_from("pq"),
            st.sampled_from(["", "lost track: 5 epochs", "lost track: 9", "model mismatch: 40"]),
        ),
        min_size=1,
        max_size=40,
    )
)
def test_flagged_shares_count_each_kind_of_reason_once(entries):
    method, reason = zip(*entries, strict=True)
    rows = pd.DataFrame({"method": method, "reason": reason, "err_x_deg": 0.0}).assign(
        valid=lambda r: r["reason"] == "", err_y_deg=0.0, err_z_deg=0.0
    )
    result = flagged_by_reason(rows, ["method"])
    kinds = {r.split(":")[0] for r in reason if r}
    assert set(result.columns) == kinds | {"flagged"}
    for name, group in rows.groupby("method"):
        assert result.loc[name, "flagged"] == pytest.approx(1.0 - group["valid"].mean())
        for kind in kinds:
            expected = group["reason"].str.startswith(kind).mean()
            assert result.loc[name, kind] == pytest.approx(expected)


def test_integrity_section_shows_the_flagged_epochs_by_reason():
    rows = pd.DataFrame(
        {
            "method": ["a", "a", "b", "b"],
            "valid": [True, False, False, False],
            "reason": ["", "lost track: gated", "inconsistent: NIS", "lost track: gated"],
            "err_x_deg": [0.1, np.nan, np.nan, np.nan],
            "err_y_deg": 0.0,
            "err_z_deg": 0.0,
            "nees": [1.0, np.nan, np.nan, np.nan],
        }
    )
    text = integrity_section(rows, ["method"])
    flagged = table(text, "Integrity", index=1)
    assert row(flagged, {"method": "a"}).to_dict() == {
        "method": "a",
        "lost track": "0.5",
        "inconsistent": "0",
        "flagged": "0.5",
    }
    assert row(flagged, {"method": "b"})["flagged"] == "1"


def test_rms_ratios_maxima_and_the_3_sigma_share():
    rows = pd.DataFrame(
        {
            "err_x_deg": [3.0, -1.0],
            "err_y_deg": [4.0, 0.0],
            "err_z_deg": [0.0, 0.0],
            **{f"bound_{a}_deg": [1.0, 1.0] for a in "xyz"},
            **{f"sigma_{a}_deg": [1.2, 1.0] for a in "xyz"},
        }
    )
    assert rms(rows["err_x_deg"]) == pytest.approx(np.sqrt(5.0))
    assert signed_max(rows["err_x_deg"]) == 3.0 and signed_max(-rows["err_x_deg"]) == -3.0
    assert rms_ratio(rows) == pytest.approx(np.sqrt(13.0 / 3.0))  # mean |e|^2 13, |b|^2 3
    error2 = np.array([25.0, 1.0])
    relative = error2.std(ddof=1) / np.sqrt(2) / error2.mean()
    assert rms_ratio_standard_error(rows) == pytest.approx(0.5 * np.sqrt(13 / 3) * relative)
    assert inside_3_sigma(rows) == 0.5  # 4 > 3 x 1.2 on y in the first row


def test_nees_interval_and_run_average():
    lo, hi = nees_interval(100)
    assert (lo, hi) == pytest.approx((chi2.ppf(0.025, 300) / 100, chi2.ppf(0.975, 300) / 100))
    rows = pd.DataFrame(
        {"trial_index": [0, 1, 0, 1, 0], "t": [0.0, 0.0, 1.0, 1.0, 2.0], "nees": [1, 3, 2, 6, 9]}
    )
    assert run_averaged_nees(rows).to_dict() == {0.0: 2.0, 1.0: 4.0}  # epoch 2 lacks trial 1


def test_markdown_numbers_and_paper_columns():
    ours = pd.DataFrame({"method": ["a", "b"], "n": [3, 4], "x": [1.23456, np.nan]})
    paper = pd.DataFrame({"method": ["a"], "x": [1.5]})
    merged = with_paper(ours, paper, ["method"], "Someone et al. 2020 Table 9")
    assert list(merged.columns) == ["method", "n", "x", "x (Someone et al. 2020 Table 9)"]
    text = markdown_table(merged, {"x": ".2f"})
    assert "| a | 3 | 1.23 | 1.5 |" in text and "| b | 4 | - | - |" in text
    values = pd.DataFrame({"r": [1.0, np.nan], "p": [2.0, np.nan], "y": [np.nan, np.nan]})
    assert joined(values, ["r", "p", "y"], ".1f", "nd").tolist() == ["1.0 / 2.0 / nd", "nd"]


@pytest.mark.parametrize("package", sorted(PAPERS))
def test_paper_values_name_their_source(package):
    values = paper_values(package)
    assert values["paper"] == PAPERS[package]
    entries = {k: v for k, v in values.items() if isinstance(v, dict)}
    assert entries
    for name, entry in entries.items():
        assert entry["source"].startswith(("Table", "Sec.", "Fig")), name
        assert paper_label(package, name) == f"{PAPERS[package]} {entry['source']}"
        if "rows" in entry:
            frame = paper_table(package, name)
            assert frame.shape == (len(entry["rows"]), len(entry["columns"]))


def test_plot_axes_draws_the_values_and_the_3_sigma_band():
    t = np.arange(6.0)
    rng = np.random.default_rng(0)
    values, sigma = rng.normal(size=(6, 3)), rng.uniform(0.1, 1.0, size=(6, 3))
    for estimate in (False, True):
        figure = plot_axes(t, values, sigma, label="m", estimate=estimate)
        centre = values if estimate else np.zeros_like(values)
        for i, axis in enumerate(figure.axes):
            np.testing.assert_array_equal(axis.lines[0].get_ydata(), values[:, i])
            band = axis.collections[0].get_paths()[0].vertices
            for edge in (centre[:, i] - 3 * sigma[:, i], centre[:, i] + 3 * sigma[:, i]):
                for point in zip(t, edge, strict=True):
                    assert np.isclose(band, point).all(axis=1).any()


def test_track_plot_and_the_report_figures_use_the_same_routine():
    """Track.plot draws its error in degrees with 3 sigma; the reports' error figure draws
    the same arrays from stored rows, and fits its y axes to the later epochs."""
    n = 8
    truth = Rotation.random(n, random_state=3)
    error = np.tile([[0.01, -0.02, 0.005]], (n, 1))
    covariance = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (n, 1, 1))
    track = Track(
        method="m",
        quaternion=(Rotation.from_rotvec(error) * truth).as_quat(),
        covariance=covariance,
        loss=np.zeros(n),
        valid=np.ones(n, dtype=bool),
        reason=np.full(n, "", dtype=object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
        t=np.arange(n, dtype=float),
    )
    from_track = track.plot(truth)
    rows = track.to_dataframe(truth)
    rows.loc[0, "err_x_deg"] = 50.0  # a large early error, left off the fitted axes
    from_rows = error_figure({"m": rows}, "title", fit_from=1.0)
    for i, (a, b) in enumerate(zip(from_track.axes, from_rows.axes, strict=True)):
        np.testing.assert_allclose(a.lines[0].get_ydata(), np.degrees(error[:, i]), atol=1e-10)
        expected = b.lines[0].get_ydata()[1:]
        np.testing.assert_allclose(a.lines[0].get_ydata()[1:], expected, atol=1e-10)
        sigma = np.degrees(np.sqrt(covariance[0, i, i]))
        bottom, top = b.get_ylim()
        limit = 1.15 * max(3 * sigma, np.abs(np.degrees(error[0, i])))
        assert (bottom, top) == pytest.approx((-limit, limit))


def test_a_run_without_rows_has_an_integrity_section_that_says_so():
    """Every trial failed: the report's integrity section and the CLI's worst share say
    there is nothing, instead of failing on the missing columns."""
    empty = pd.DataFrame()
    assert "No rows" in integrity_section(empty, ["method"])
    share, group = worst_share(empty, ["method"])
    assert np.isnan(share) and group == ""
