"""Summary statistics per setting and method, invalid-row reasons."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from attopt.experiments.reporting.statistics import valid_mask
from attopt.experiments.sweep import summarise
from attopt.experiments.sweep.aggregate import invalid_reasons

NAN = float("nan")


def rows() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "setting_index": [0, 0, 0, 0, 1],
            "trial_index": [0, 1, 2, 3, 0],
            "snr": [10.0, 10.0, 10.0, 10.0, 20.0],
            "method": ["q", "q", "q", "q", "q"],
            "err_x_deg": [3.0, -1.0, 100.0, NAN, 2.0],
            "err_y_deg": [4.0, 1.0, 100.0, NAN, 0.0],
            "err_z_deg": [0.0, 1.0, 100.0, NAN, 0.0],
            "valid": [True, True, False, True, True],
            "reason": ["", "", "diverged", "", ""],
            "bound_x_deg": [1.0, 3.0, 50.0, 1.0, 1.0],
            "bound_y_deg": [1.0, 1.0, 1.0, 1.0, 1.0],
            "bound_z_deg": [2.0, 2.0, 2.0, 2.0, 2.0],
        }
    )


def no_failures() -> pd.DataFrame:
    return pd.DataFrame(columns=["setting_index", "trial_index", "error_type", "message"])


def test_statistics_over_valid_rows():
    summary = summarise(rows(), no_failures(), setting_columns=["snr"], group_by=["method"])
    first = summary.iloc[0]
    assert (first["n_rows"], first["n_valid"]) == (4, 2)
    assert first["valid_fraction"] == pytest.approx(0.5)
    assert first["roll_rms_deg"] == pytest.approx(np.sqrt((9 + 1) / 2))
    assert first["pitch_rms_deg"] == pytest.approx(np.sqrt((16 + 1) / 2))
    assert first["yaw_rms_deg"] == pytest.approx(np.sqrt(1 / 2))
    assert first["total_rms_deg"] == pytest.approx(np.sqrt((25 + 3) / 2))
    assert first["roll_mean_deg"] == pytest.approx(1.0)
    assert first["p50_deg"] == pytest.approx((5 + np.sqrt(3)) / 2)
    assert first["p95_deg"] == pytest.approx(np.sqrt(3) + 0.95 * (5 - np.sqrt(3)))
    assert first["roll_bound_deg"] == pytest.approx(np.sqrt((1 + 9) / 2))
    assert first["roll_ratio"] == pytest.approx(1.0)
    assert first["yaw_ratio"] == pytest.approx(np.sqrt(1 / 2) / 2)
    assert list(summary["snr"]) == [10.0, 20.0] and list(summary["failed_trials"]) == [0, 0]


def test_without_bounds_there_are_no_ratio_columns():
    plain = rows().drop(columns=["bound_x_deg", "bound_y_deg", "bound_z_deg"])
    summary = summarise(plain, no_failures(), setting_columns=["snr"], group_by=["method"])
    assert not [c for c in summary.columns if "bound" in c or "ratio" in c]


def test_failed_trials_are_counted_and_settings_without_rows_kept():
    failures = pd.DataFrame(
        {
            "setting_index": [0, 2, 2],
            "trial_index": [4, 0, 1],
            "snr": [10.0, 30.0, 30.0],
            "error_type": ["ValueError"] * 3,
            "message": ["x"] * 3,
        }
    )
    summary = summarise(rows(), failures, setting_columns=["snr"], group_by=["method"])
    assert list(summary["setting_index"]) == [0, 1, 2]
    assert list(summary["failed_trials"]) == [1, 0, 2]
    assert summary.iloc[2]["n_rows"] == 0 and summary.iloc[2]["snr"] == 30.0


def test_missing_error_columns_are_named():
    with pytest.raises(ValueError, match="err_z_deg"):
        summarise(
            rows().drop(columns="err_z_deg"),
            no_failures(),
            setting_columns=[],
            group_by=["method"],
        )


def test_invalid_reasons_counted_per_method():
    reasons = invalid_reasons(rows(), ["method"])
    assert list(reasons.columns) == ["method", "reason", "rows"]
    assert set(reasons.itertuples(index=False, name=None)) == {
        ("q", "diverged", 1),
        ("q", "(no reason given)", 1),
    }


def test_experiment_summary_columns_are_joined_per_group():
    def largest_roll(frame: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
        return frame.groupby(keys).agg(roll_max_abs_deg=("err_x_deg", lambda s: s.abs().max()))

    summary = summarise(
        rows(),
        no_failures(),
        setting_columns=["snr"],
        group_by=["method"],
        extra=lambda frame, keys: largest_roll(frame, keys).reset_index(),
    )
    assert list(summary["roll_max_abs_deg"]) == [100.0, 2.0]
    assert summary["n_rows"].tolist() == [4, 1]


def _rows_with_axes(errors: np.ndarray, valid: np.ndarray) -> pd.DataFrame:
    n = len(errors)
    return pd.DataFrame(
        {
            "setting_index": 0,
            "method": np.where(np.arange(n) % 2, "a", "b"),
            **{f"err_{a}_deg": errors[:, i] for i, a in enumerate("xyz")},
            **{f"bound_{a}_deg": np.abs(errors[:, i]) + 1.0 for i, a in enumerate("xyz")},
            "valid": valid,
        }
    )


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-10, 10, allow_nan=False), st.floats(-10, 10, allow_nan=False), st.booleans()
        ),
        min_size=1,
        max_size=12,
    )
)
def test_an_unobservable_axis_is_nan_in_every_summary_column(data):
    """Yaw NaN on every row (an axis the estimator cannot see): the yaw columns are NaN, not
    0, and every other column is bit-identical to the summary of the same rows with yaw 0."""
    roll_pitch = np.array([d[:2] for d in data])
    valid = np.array([d[2] for d in data])
    unseen = np.column_stack([roll_pitch, np.full(len(data), np.nan)])
    zero = np.column_stack([roll_pitch, np.zeros(len(data))])
    a, b = _rows_with_axes(unseen, valid), _rows_with_axes(zero, valid)
    b["bound_z_deg"] = np.nan
    a["bound_z_deg"] = np.nan
    kwargs = {"setting_columns": [], "group_by": ["method"]}
    with_nan, with_zero = (
        summarise(a, no_failures(), **kwargs),
        summarise(b, no_failures(), **kwargs),
    )
    yaw = [c for c in with_nan.columns if c.startswith("yaw_")]
    assert yaw == ["yaw_rms_deg", "yaw_mean_deg", "yaw_bound_deg", "yaw_ratio"]
    assert with_nan[yaw].isna().all().all()
    assert (with_zero.loc[with_zero["n_valid"] > 0, "yaw_rms_deg"] == 0).all()
    pd.testing.assert_frame_equal(with_nan.drop(columns=yaw), with_zero.drop(columns=yaw))


def test_rows_valid_with_an_unobservable_axis_and_invalid_when_all_nan():
    errors = np.array([[1.0, 2.0, NAN], [NAN, NAN, NAN], [3.0, 4.0, 1.0], [3.0, 4.0, NAN]])
    frame = _rows_with_axes(errors, np.array([True, True, True, False]))
    assert valid_mask(frame).tolist() == [True, False, True, False]
    summary = summarise(
        frame.assign(method="a"), no_failures(), setting_columns=[], group_by=["method"]
    )
    line = summary.iloc[0]
    assert (line["n_rows"], line["n_valid"]) == (4, 2)
    assert line["yaw_rms_deg"] == 1.0  # over the rows that have a yaw error
    assert line["total_rms_deg"] == pytest.approx(np.sqrt((5.0 + 26.0) / 2))
