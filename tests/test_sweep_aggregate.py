"""Summary statistics per setting and method, invalid-row reasons."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

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
