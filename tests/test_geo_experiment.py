"""The ``geo-snr-stations`` experiment's trial (``experiments/geo_snr_stations/``;
Pimienta-Penalver and Crassidis).

One quick-setting trial with the manoeuvre (one hour, 60 s epochs), run twice
with the same seed: the rows must be identical, complete and sane.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.experiment import ReportContext
from attopt.experiments.geo_snr_stations.experiment import (
    EXPERIMENT,
    PARAMETERS,
    summary_columns,
    trial,
)
from attopt.experiments.geo_snr_stations.report import report
from attopt.experiments.geo_snr_stations.scenario import MANOEUVRE_START_S
from attopt.experiments.registry import get_experiment
from attopt.experiments.sweep import summarise
from attopt.solvers.geo.m2m4 import snr_table
from tests.report_tables import row, table

SETTING = {**PARAMETERS, **EXPERIMENT.quick_parameters, "manoeuvre": True}
METHODS = {"cone", "lsq", "nlp", "usque", "usque_detect", "fg_batch"}


@pytest.fixture(scope="module")
def rows() -> pd.DataFrame:
    return trial(SETTING, np.random.SeedSequence(4))


def _rms(frame: pd.DataFrame, prefix: str) -> np.ndarray:
    values = frame[[f"{prefix}_x_deg", f"{prefix}_y_deg"]].to_numpy()
    return np.sqrt(np.mean(values**2, axis=0))


def test_trial_is_reproducible(rows: pd.DataFrame) -> None:
    again = trial(SETTING, np.random.SeedSequence(4))
    pd.testing.assert_frame_equal(rows, again)


def test_rows_are_complete_and_yaw_is_flagged_unobservable(rows: pd.DataFrame) -> None:
    assert get_experiment("geo-snr-stations") is EXPERIMENT
    n = int(SETTING["duration_s"] / SETTING["step_s"])
    assert rows.groupby("method").size().to_dict() == dict.fromkeys(METHODS, n)
    assert rows["valid"].all()
    assert (rows["err_z_deg"] == 0).all() and not rows["yaw_observable"].any()
    filters = rows["method"].isin(["usque", "usque_detect", "fg_batch"])
    assert rows.loc[filters, "yaw_err_deg"].notna().all()
    assert rows.loc[~filters, "yaw_err_deg"].isna().all()


def test_errors_match_their_bounds(rows: pd.DataFrame) -> None:
    by = dict(iter(rows.groupby("method")))
    # least squares and the NLP are efficient: RMS within 30 % of the CRB (measured 1.0)
    for method in ("lsq", "nlp"):
        ratio = _rms(by[method], "err") / _rms(by[method], "bound")
        assert np.all((ratio > 0.7) & (ratio < 1.3)), (method, ratio)
    # cones use three stations exactly: worse than their CRB, still below 0.02 deg
    assert np.all(_rms(by["cone"], "err") < 0.02)
    # filters and smoother within 1.5 times their own sigma (measured 0.8-1.2)
    for method in ("usque", "usque_detect", "fg_batch"):
        ratio = _rms(by[method], "err") / _rms(by[method], "sigma")
        assert np.all(ratio < 1.5), (method, ratio)


def test_manoeuvre_detected_and_summarised(rows: pd.DataFrame) -> None:
    labelled = rows.assign(trial_index=0, manoeuvre=True)
    summary = summary_columns(labelled, ["manoeuvre", "method"]).set_index("method")
    assert summary.loc["usque_detect", "restarts_per_trial"] >= 1
    delay = summary.loc["usque_detect", "detection_delay_s"]
    assert 0 < delay <= 2 * SETTING["step_s"]
    detected = rows.loc[rows["method"] == "usque_detect"]
    assert detected.loc[detected["detected"].astype(bool), "t_s"].min() > MANOEUVRE_START_S


def test_report_tables_from_the_trials_rows(rows: pd.DataFrame, tmp_path) -> None:
    """The report of one trial per manoeuvre setting: Table 3 beside the paper's, the bounds
    table equal to the summary, the restarts, integrity without a NEES, the figure."""
    labelled = pd.concat(
        [
            trial({**SETTING, "manoeuvre": False}, np.random.SeedSequence(4)).assign(
                setting_index=0, manoeuvre=False
            ),
            rows.assign(setting_index=1, manoeuvre=True),
        ],
        ignore_index=True,
    ).assign(trial_index=0)
    summary = summarise(
        labelled,
        pd.DataFrame(columns=["setting_index"]),
        setting_columns=["manoeuvre"],
        group_by=EXPERIMENT.group_by,
        extra=summary_columns,
    )
    text = report(ReportContext(SETTING, labelled, summary, tmp_path, "attopt run geo"))
    table3 = table(text, "Pimienta-Penalver and Crassidis Table 3: M2M4 SNR estimator")
    assert table3.iloc[:, -1].tolist() == ["0.020", "2.025", "4.034", "5.980", "7.990", "10.040"]
    ours = snr_table(np.random.default_rng(0), 1024, 300)
    assert table3["ours mean (dB)"].tolist() == [f"{m:.3f}" for m in ours.mean_db]
    bounds = table(text, "Roll and pitch beside the bound")
    for _, line in summary.iterrows():
        cells = row(bounds, {"manoeuvre": str(line["manoeuvre"]), "method": line["method"]})
        assert cells["roll RMS"] == f"{line['roll_rms_deg']:.2e}"
        assert cells["pitch bound"] == f"{line['pitch_bound_deg']:.2e}"
    sensitivity = table(
        text,
        "Boresight error with perturbed RF parameters (Pimienta-Penalver and Crassidis Fig. 6)",
    )
    exact = row(sensitivity, {"method": "least_squares", "P_t (kW)": "12"})
    assert exact["D = 12 m"] == "0.0000"  # the true parameters recover the boresight
    detection = table(text, "Manoeuvre detection")
    detected = labelled[(labelled["method"] == "usque_detect") & labelled["detected"].astype(bool)]
    restarts = ", ".join(f"{t:g}" for t in detected["t_s"])
    assert row(detection, {"manoeuvre": "True"})["restarts at t (s)"] == restarts
    assert row(detection, {"manoeuvre": "False"})["restarts at t (s)"] == "none"
    integrity = table(text, "Integrity")
    assert set(integrity["mean NEES"]) == {"n/a"}  # the rows carry no NEES
    assert set(integrity["valid"]) == {"1.000"}
    assert (tmp_path / "usque_3sigma.png").stat().st_size > 10_000
