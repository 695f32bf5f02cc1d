"""The ``doa-ground`` report on synthetic rows with hand-computable errors (no sweep needed).

Two settings (0 dB at ``L = 100`` and ``L = 10``), three trials, the gyro-aided
methods in the first two.  Settled errors per trial (deg, body x axis; the
Euler errors are ``(e, 2 e, 3 e)``; signs alternate over the rows):

* ``ekf_yang2014_q1e-09``: 0.3, 0.3, 1.2; ``ekf_yang2014_q1e-12`` half of that;
* each RTS 0.4 times its EKF's on the first two trials (same as the EKF's on the
  third), ``fg_batch`` 0.18, ``mekf`` 0.5 and ``bls_yang2014`` 0.03 (the last three
  in the first two trials); ``crb_*`` 0.02 per axis on the EKF rows, 0.01 on
  the RTS rows;
* ``wahba``: 2.0 on every other settled row, invalid (NaN) on the rest;
* converging rows (t < 100 s) 10 deg, valid, which no RMSE may include;
* DOAs: 100 per trial, 50, 75 and 75 accepted, theta MSE ``1 + trial`` deg^2; per
  station (their own numbers), ``North`` 60 per trial with 40, 45, 45 accepted and theta
  MSE ``1 + trial``, ``South`` 40 with 10, 30, 30 accepted and theta MSE 4.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.doa_ground.methods import attitude_methods
from attopt.experiments.doa_ground.report import (
    attitude_table,
    consistency_table,
    doa_table,
    report,
    runtime_table,
    shared_trials,
)
from attopt.experiments.experiment import ReportContext
from attopt.solvers.start_hypotheses import AMBIGUOUS
from tests.report_tables import row, table

SETTLE_S = 100.0
ROW_STEP_S = 10.0
N_ROWS = 30
TRIALS = 3
FILTER_TRIALS = 2
SETTINGS = ((0.0, 100), (0.0, 10))
EKF_ERROR = (0.3, 0.3, 1.2)
NEES_SIGMA = 0.1
"""Every method's own sigma (deg, one axis): ``nees = (error / 0.1)^2``."""
PARAMETERS: dict[str, Any] = {
    "table1_snr_db": [0.0],
    "table1_snapshots": 100,
    "table2_snapshots": [10, 100],
    "table2_snr_db": 0.0,
    "settle_s": SETTLE_S,
    "row_step_s": ROW_STEP_S,
    "process_noise": [1e-9, 1e-12],
    "filters": ["mekf", "fg_batch"],
    "filter_trials": FILTER_TRIALS,
    "step_s": 0.25,
    "stations": [
        {"name": "North", "latitude_deg": 60.0, "longitude_deg": 10.0, "height_m": 100.0},
        {"name": "South", "latitude_deg": -30.0, "longitude_deg": 20.0, "height_m": 0.0},
    ],
}


def _frame(method: str, error: float, **extra: Any) -> pd.DataFrame:
    """Rows of one pass: 10 deg while converging, then ``error`` with alternating signs."""
    t = ROW_STEP_S * np.arange(N_ROWS)
    settled = t >= SETTLE_S
    signed = np.where(settled, error, 10.0) * (-1.0) ** np.arange(N_ROWS)
    columns = {
        "method": method,
        "t_s": t,
        "phase": np.where(settled, "settled", "converging"),
        "err_x_deg": signed,
        "err_y_deg": 0.0,
        "err_z_deg": 0.0,
        **{f"euler_{n}_err_deg": k * signed for k, n in enumerate(("yaw", "roll", "pitch"), 1)},
        **{f"sigma_{a}_deg": NEES_SIGMA for a in "xyz"},
        "nees": (signed / NEES_SIGMA) ** 2,
        "valid": True,
        "reason": "",
    }
    return pd.DataFrame(columns | extra)


def _filter_extra(rate_error: np.ndarray | float, bound: float, runtime: float) -> dict:
    return {
        **{f"rate_err_{a}_deg_s": rate_error for a in "xyz"},
        **{f"pbound_{a}_deg": bound for a in "xyz"},
        "runtime_s": runtime,
    }


def _wahba() -> pd.DataFrame:
    frame = _frame("wahba", 2.0, **{f"bound_{a}_deg": 1.0 for a in "xyz"})
    invalid = (np.arange(N_ROWS) % 2 == 1) & (frame["phase"] == "settled")
    frame.loc[invalid, [c for c in frame if c.endswith("err_deg")]] = np.nan
    frame.loc[invalid, "valid"] = False
    frame.loc[invalid, "reason"] = "fewer than two stations"
    return frame


def _trial(trial: int, q_scales: Mapping[str, float], filters: bool) -> list[pd.DataFrame]:
    """Every method of one trial (``filters``: with ``mekf`` and ``fg_batch``)."""
    rate = np.where(ROW_STEP_S * np.arange(N_ROWS) < 50.0, 1.0, 0.01)
    ekf = EKF_ERROR[trial]
    rts_scale = 0.4 if trial < FILTER_TRIALS else 1.0
    frames = [_wahba()]
    crb = {f"crb_{a}_deg": 0.02 for a in "xyz"}
    smoother_crb = {f"crb_{a}_deg": 0.01 for a in "xyz"}
    for q, scale in q_scales.items():
        extra = _filter_extra(rate, 0.2, runtime=trial + 1.0)
        frames.append(_frame(f"ekf_yang2014_q{q}", scale * ekf, **extra, **crb))
        frames.append(
            _frame(f"rts_yang2014_q{q}", rts_scale * scale * ekf, **extra, **smoother_crb)
        )
    if filters:
        frames.append(_frame("bls_yang2014", 0.03, **_filter_extra(rate, 0.02, runtime=3.0)))
        frames.append(_frame("mekf", 0.5, **_filter_extra(np.nan, 0.1, runtime=5.0)))
        frames.append(_frame("fg_batch", 0.18, **_filter_extra(np.nan, 0.1, 10.0 * (trial + 1))))
    music = {"doa_count": 100, "doa_crb_theta_deg2": 0.01, "doa_crb_phi_deg2": 0.04}
    accepted = 50 if trial == 0 else 75
    music |= {"doa_accepted": accepted, "doa_theta_mse_deg2": 1.0 + trial}
    music |= {"doa_phi_mse_deg2": 4.0, "method": "music", "phase": "all", "valid": False}
    stations = {
        1: (60, 40 if trial == 0 else 45, 1.0 + trial),
        2: (40, 10 if trial == 0 else 30, 4.0),
    }
    for k, (count, taken, theta) in stations.items():
        music |= {f"doa_count_station{k}": count, f"doa_accepted_station{k}": taken}
        music |= {f"doa_theta_mse_station{k}_deg2": theta, f"doa_phi_mse_station{k}_deg2": 1.0}
        music |= {
            f"doa_crb_theta_station{k}_deg2": 0.01 * k**2,
            f"doa_crb_phi_station{k}_deg2": 1.0,
        }
    return [*frames, pd.DataFrame([music])]


def _rows(q_scales: Mapping[str, float] | None = None, filters: bool = True) -> pd.DataFrame:
    q_scales = {"1e-09": 1.0, "1e-12": 0.5} if q_scales is None else q_scales
    frames = []
    for index, (snr, snapshots) in enumerate(SETTINGS):
        for trial in range(TRIALS):
            for frame in _trial(trial, q_scales, filters and trial < FILTER_TRIALS):
                frames.append(
                    frame.assign(
                        setting_index=index, trial_index=trial, snr_db=snr, snapshots=snapshots
                    )
                )
    return pd.concat(frames, ignore_index=True)


def _report(rows: pd.DataFrame, out_dir: Path, parameters: Mapping[str, Any] = PARAMETERS) -> str:
    return report(
        ReportContext(parameters=parameters, rows=rows, summary=pd.DataFrame(), out_dir=out_dir)
    )


def test_attitude_rmses_pool_the_settled_valid_rows_of_all_trials() -> None:
    rows = _rows()
    methods = attitude_methods(rows, PARAMETERS)
    assert methods == [
        "ekf_yang2014_q1e-09",
        "ekf_yang2014_q1e-12",
        "rts_yang2014_q1e-09",
        "rts_yang2014_q1e-12",
        "bls_yang2014",
        "wahba",
        "mekf",
        "fg_batch",
    ]
    table = attitude_table(rows, methods)
    ekf = table.loc[(0.0, 100, "ekf_yang2014_q1e-09")]
    pooled = np.sqrt(np.mean(np.square(EKF_ERROR)))  # eq. 34: equal rows per trial
    np.testing.assert_allclose(
        ekf[["yaw_rmse_deg", "roll_rmse_deg", "pitch_rmse_deg"]], [pooled, 2 * pooled, 3 * pooled]
    )
    assert ekf["total_rmse_deg"] == pytest.approx(pooled)
    assert ekf["bound_total_deg"] == pytest.approx(0.2 * np.sqrt(3.0))
    assert (ekf["valid"], ekf["trials"]) == (1.0, 3)
    assert table.loc[(0.0, 10, "ekf_yang2014_q1e-12"), "total_rmse_deg"] == pytest.approx(
        0.5 * pooled
    )
    wahba = table.loc[(0.0, 100, "wahba")]
    assert wahba["total_rmse_deg"] == pytest.approx(2.0)  # the invalid rows do not count
    assert wahba["ratio"] == pytest.approx(2.0 / np.sqrt(3.0))  # bound_* for wahba
    assert wahba["valid"] == pytest.approx(0.5)
    fg = table.loc[(0.0, 100, "fg_batch")]
    assert (fg["total_rmse_deg"], fg["trials"]) == (pytest.approx(0.18), 2)


def test_rows_the_start_check_flags_count_in_the_rmse_not_the_valid_share() -> None:
    """The paper's EKF's estimates stay in its RMSE where the start check has not confirmed
    them (the rows show the unchecked run's errors, valid False); the valid share and the
    NEES statistics count only the confirmed rows; other flags remove rows from both."""
    rows = _rows()
    ekf = (rows["method"] == "ekf_yang2014_q1e-09") & (rows["phase"] == "settled")
    methods = ["ekf_yang2014_q1e-09"]
    before = attitude_table(rows, methods).loc[(0.0, 100, "ekf_yang2014_q1e-09")]
    flagged = ekf & (rows["trial_index"] == 0)
    rows.loc[flagged, "valid"] = False
    rows.loc[flagged, "reason"] = AMBIGUOUS
    after = attitude_table(rows, methods).loc[(0.0, 100, "ekf_yang2014_q1e-09")]
    assert after["total_rmse_deg"] == before["total_rmse_deg"]
    assert after["valid"] == pytest.approx(2 / 3)
    nees = consistency_table(rows, methods).loc[(0.0, 100, "ekf_yang2014_q1e-09", "settled")]
    rows.loc[flagged, "reason"] = "inconsistent"
    other = attitude_table(rows, methods).loc[(0.0, 100, "ekf_yang2014_q1e-09")]
    assert other["total_rmse_deg"] != before["total_rmse_deg"] and other["trials"] == 2
    assert (
        nees["mean"]
        == consistency_table(rows, methods).loc[
            (0.0, 100, "ekf_yang2014_q1e-09", "settled"), "mean"
        ]
    )


def test_doa_rmse_weights_each_trial_by_its_accepted_estimates() -> None:
    doa = doa_table(_rows()).loc[(0.0, 100)]
    # accepted 50, 75, 75 with theta MSE 1, 2, 3
    assert doa["theta_rmse_deg"] == pytest.approx(np.sqrt((50 + 150 + 225) / 200.0))
    assert doa["phi_rmse_deg"] == pytest.approx(2.0)
    assert (doa["crb_theta_deg"], doa["accepted"]) == (pytest.approx(0.1), pytest.approx(2 / 3))


def _line(text: str, heading: str, **where: str) -> pd.Series:
    return row(table(text, heading), {k.replace("_", " "): v for k, v in where.items()})


def test_smoother_ratios_use_only_the_trials_fg_batch_ran_in(tmp_path: Path) -> None:
    rows = _rows()
    assert set(shared_trials(rows)["trial_index"]) == set(range(FILTER_TRIALS))
    text = _report(rows, tmp_path)
    line = _line(text, "Smoothers against the EKF on the same data", SNR_dB="0", L="100")
    # over all three trials RTS / EKF would be 0.56 (1e-09), not 0.40
    assert line["trials"] == "2"
    assert (line["EKF Q = 1e-09"], line["EKF Q = 1e-12"]) == ("0.300", "0.150")
    assert (line["RTS Q = 1e-09"], line["RTS Q = 1e-12"]) == ("0.120", "0.060")
    assert line["bls_yang2014 (CRB)"] == "0.0300 (-)"  # the synthetic bls rows carry no crb_*
    assert line["mekf"] == "0.500"
    assert line["fg_batch (pass bound)"] == f"0.180 ({0.1 * np.sqrt(3.0):.3f})"
    ratios = ["RTS / EKF 1e-09", "RTS / EKF 1e-12", "bls_yang2014 / EKF 1e-09"]
    ratios += ["bls_yang2014 / EKF 1e-12", "fg_batch / EKF 1e-09", "fg_batch / EKF 1e-12"]
    assert line[ratios].tolist() == ["0.40", "0.40", "0.10", "0.20", "0.60", "1.20"]


def test_summary_has_one_line_per_setting(tmp_path: Path) -> None:
    """EKF Euler RMSEs at both Q (the paper's beside the lower), the RTS and batch
    least-squares totals and the EKF's CRB total."""
    text = _report(_rows(), tmp_path)
    pooled = np.sqrt(np.mean(np.square(EKF_ERROR)))
    rts = 0.5 * np.sqrt(np.mean(np.square([0.12, 0.12, 1.2])))
    euler = ", ".join(f"{k * pooled:.3f}" for k in (1, 2, 3))
    low = ", ".join(f"{0.5 * k * pooled:.3f}" for k in (1, 2, 3))
    summary = table(text, "Summary")
    line = row(summary, {"SNR dB": "0", "L": "100"})
    assert line.tolist() == [
        "0",
        "100",
        "1.458 / 0.100 (0.315)",
        "2.000 / 0.200 (0.308)",
        "0.667",
        euler,
        f"{low} (0.083, 0.061, 0.094)",
        f"{rts:.3f}",
        "0.0300",
        f"{0.01 * np.sqrt(3.0):.4f}",
    ]
    assert summary["L"].tolist() == ["10", "100"]


def test_consistency_pools_the_valid_rows_per_phase(tmp_path: Path) -> None:
    """EKF (1e-09) NEES 9, 9 and 144 in the three trials once settled (mean 54, median 9,
    one third above the 99.99% quantile 21.1), 10^4 while converging; ``wahba``'s
    invalid rows do not count."""
    rows = _rows()
    table_ = consistency_table(rows, attitude_methods(rows, PARAMETERS))
    ekf = table_.loc[(0.0, 100, "ekf_yang2014_q1e-09", "settled")]
    assert ekf.tolist() == pytest.approx([54.0, 9.0, 1.0 / 3.0])
    assert table_.loc[(0.0, 100, "ekf_yang2014_q1e-09", "converging"), "above"] == 1.0
    assert table_.loc[(0.0, 100, "wahba", "settled"), "mean"] == pytest.approx(400.0)
    text = _report(rows, tmp_path)
    line = _line(text, "Consistency", SNR_dB="0", L="100", method="ekf_yang2014_q1e-09")
    assert line.iloc[3:].tolist() == ["54", "9", "0.333", "1.000"]


def test_integrity_takes_every_phase_of_every_trial(tmp_path: Path) -> None:
    """EKF (1e-09) at 0 dB, L = 100: 10 converging rows per trial (NEES 10^4, all beyond),
    20 settled with NEES 9, 9 and 144 in the three trials; ``wahba`` valid on 10 of its 20
    settled rows and all 10 converging."""
    text = _report(_rows(), tmp_path)
    section = table(text, "Integrity")
    ekf = row(section, {"snr_db": "0", "snapshots": "100", "method": "ekf_yang2014_q1e-09"})
    mean = (30 * 1e4 + 40 * 9 + 20 * 144) / 90
    assert ekf.iloc[3:].tolist() == ["90", "1.000", "90", f"{50 / 90:.3g}", f"{mean:.3g}"]
    wahba = row(section, {"snr_db": "0", "snapshots": "100", "method": "wahba"})
    assert wahba["valid"] == f"{60 / 90:.3f}" and wahba["valid epochs with a NEES"] == "60"


def test_missing_methods_and_settings_show_a_dash(tmp_path: Path) -> None:
    rows = _rows()
    missing = (rows["snapshots"] == 10) & rows["method"].isin(["mekf", "music"])
    text = _report(rows[~missing], tmp_path)
    attitude = table(text, "Yang et al. 2014 Table 2 beside ours", 1)
    mekf = row(attitude, {"L": "10", "method": "mekf"})
    assert set(mekf.iloc[3:].tolist()) == {"-", ""}
    doa = row(table(text, "Yang et al. 2014 Table 2 beside ours"), {"L": "10"})
    assert doa.tolist() == ["0", "10", "-", "-", "-", "-", "-", "0.781", "0.684"]
    ekf = row(
        table(text, "Yang et al. 2014 Table 1 beside ours", 1),
        {"L": "100", "method": "ekf_yang2014_q1e-09"},
    )
    assert ekf.iloc[3:7].tolist() == ["0.735", "1.470", "2.205", "0.083 / 0.061 / 0.094"]


def test_report_writes_the_convergence_figure_and_times(tmp_path: Path) -> None:
    text = _report(_rows(), tmp_path)
    assert (tmp_path / "doa_convergence.png").stat().st_size > 0
    assert "![doa_convergence.png](doa_convergence.png)" in text
    convergence = table(text, "Convergence (Yang et al. 2014 Sec. 6, Figs. 6-7)")
    # pitch errors 3 e: 0.9 deg at Q = 1e-09, 0.45 deg at Q = 1e-12 once settled
    assert row(convergence, {"row": "EKF Q = 1e-09"}).iloc[1:].tolist() == ["-", "50"]
    assert row(convergence, {"row": "EKF Q = 1e-12"}).iloc[1:].tolist() == ["100", "50"]
    assert row(convergence, {"row": "Yang et al. 2014 Sec. 6, Figs. 6-7"}).iloc[1] == "within 1500"


def test_stations_table_follows_the_configured_stations(tmp_path: Path) -> None:
    """One line per station at 0 dB, L = 100 (the paper's first simulation), from its own
    columns: theta RMSE weighted by its accepted estimates, CRB by its estimates."""
    stations = table(_report(_rows(), tmp_path), "Stations")
    assert stations["station"].tolist() == ["North", "South"]
    north, south = row(stations, {"station": "North"}), row(stations, {"station": "South"})
    assert north.iloc[1:5].tolist() == ["60.000", "10.000", "100", "15"]  # 60 DOAs x 0.25 s
    theta = np.sqrt((40 * 1.0 + 45 * 2.0 + 45 * 3.0) / 130.0)
    assert north["accepted"] == f"{130 / 180:.3f}"
    assert north["theta RMSE / CRB"] == f"{theta:.3f} / 0.100"
    assert south["visible per pass (s)"] == "10" and south["accepted"] == f"{70 / 120:.3f}"
    assert south["theta RMSE / CRB"] == "2.000 / 0.200"
    assert south["phi RMSE / CRB"] == "1.000 / 1.000"


def test_runtime_is_the_mean_over_passes() -> None:
    rows = _rows()
    runtimes = runtime_table(rows, attitude_methods(rows, PARAMETERS))
    assert runtimes.loc["ekf_yang2014_q1e-09"].tolist() == [6, 2.0]  # 2 settings x 3 trials
    assert runtimes.loc["fg_batch"].tolist() == [4, 15.0]
    assert "wahba" not in runtimes.index  # no runtime_s


def test_quick_run_subset_without_fg_batch_and_parameters(tmp_path: Path) -> None:
    """One Q, no gyro-aided filters, and none of the list parameters given."""
    rows = _rows(q_scales={"1e-09": 1.0}, filters=False)
    parameters = {"settle_s": SETTLE_S, "row_step_s": ROW_STEP_S}
    text = _report(rows, tmp_path, parameters)
    smoothers = table(text, "Smoothers against the EKF on the same data")
    assert list(smoothers.columns) == [
        "SNR dB",
        "L",
        "trials",
        "EKF Q = 1e-09",
        "RTS Q = 1e-09",
        "RTS / EKF 1e-09",
    ]
    pooled = np.sqrt(np.mean(np.square(EKF_ERROR)))
    rts = np.sqrt(np.mean(np.square([0.12, 0.12, 1.2])))
    line = row(smoothers, {"L": "100"})
    assert line.tolist() == ["0", "100", "3", f"{pooled:.3f}", f"{rts:.3f}", f"{rts / pooled:.2f}"]
    assert "| mekf |" not in text and "| fg_batch |" not in text
    assert (tmp_path / "doa_convergence.png").exists()
