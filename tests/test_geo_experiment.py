"""The ``geo-snr-stations`` experiment's trial (``experiments/geo_snr_stations/``;
Pimienta-Penalver and Crassidis).

One quick-setting trial with the manoeuvre (one hour, 60 s epochs), run twice
with the same seed: the rows must be identical, complete and sane.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from attopt.experiments.experiment import ReportContext
from attopt.experiments.geo_snr_stations.experiment import (
    EXPERIMENT,
    summary_columns,
    trial,
)
from attopt.experiments.geo_snr_stations.los_study import los_geometry_study
from attopt.experiments.geo_snr_stations.parameters import TABLE2_STATIONS, GeoWorld
from attopt.experiments.geo_snr_stations.report import report
from attopt.experiments.geo_snr_stations.scenario import build_geo_snr_scenario
from attopt.experiments.metrics import pointing_error
from attopt.experiments.registry import get_experiment
from attopt.experiments.sweep import summarise
from attopt.formulations.geo_link import attitude_pointing
from attopt.solvers.geo.m2m4 import snr_table
from tests.report_tables import row, table

PARAMETERS = EXPERIMENT.parameters
SETTING = {**PARAMETERS, **EXPERIMENT.quick_parameters, "manoeuvre": True}
METHODS = {"cone", "lsq", "nlp", "usque", "usque_detect", "fg_batch"}
MANOEUVRE_START_S = GeoWorld().attitude.manoeuvre.start_s
MANOEUVRE_S = GeoWorld().attitude.manoeuvre.duration_s


@pytest.fixture(scope="module")
def rows() -> pd.DataFrame:
    return trial(SETTING, np.random.SeedSequence(4))


def _rms(frame: pd.DataFrame, prefix: str) -> np.ndarray:
    """RMS over the valid rows."""
    values = frame.loc[frame["valid"], [f"{prefix}_x_deg", f"{prefix}_y_deg"]].to_numpy()
    return np.sqrt(np.mean(values**2, axis=0))


def test_trial_is_reproducible(rows: pd.DataFrame) -> None:
    again = trial(SETTING, np.random.SeedSequence(4))
    pd.testing.assert_frame_equal(rows, again)


def test_rows_are_complete_and_yaw_is_nan_everywhere(rows: pd.DataFrame) -> None:
    assert get_experiment("geo-snr-stations") is EXPERIMENT
    n = int(SETTING["duration_s"] / SETTING["step_s"])
    assert rows.groupby("method").size().to_dict() == dict.fromkeys(METHODS, n)
    assert not rows["yaw_observable"].any()
    # every row is valid but USQUE's and the smoother's through the manoeuvre they do not
    # model: USQUE's consistency test flags it (its covariance no longer covers its
    # error), the smoother's gyro fault test the epochs the turn spans
    flagged = rows[~rows["valid"]]
    assert set(flagged["method"]) == {"usque", "fg_batch"}
    assert (flagged["t_s"] > MANOEUVRE_START_S).all()
    assert flagged["reason"].str.startswith("inconsistent").all()
    smoothed = flagged[flagged["method"] == "fg_batch"]
    assert smoothed["reason"].str.startswith("inconsistent: the gyro up to").all()
    assert (smoothed["t_s"] <= MANOEUVRE_START_S + MANOEUVRE_S + SETTING["step_s"]).all()
    rows = rows[rows["valid"]]
    assert rows["err_z_deg"].isna().all()
    assert rows[["err_x_deg", "err_y_deg"]].notna().all().all()
    filters = rows["method"].isin(["usque", "usque_detect", "fg_batch"])
    assert rows.loc[filters, "yaw_err_deg"].notna().all()
    assert rows.loc[~filters, "yaw_err_deg"].isna().all()
    # the NLP's variance about the boresight is infinite: its yaw sigma is NaN, not inf
    nlp = rows[rows["method"] == "nlp"]
    assert nlp["sigma_z_deg"].isna().all() and nlp["sigma_x_deg"].notna().all()
    assert np.isfinite(
        rows[["sigma_x_deg", "sigma_y_deg", "sigma_z_deg"]].to_numpy()[filters]
    ).all()


def test_rows_store_the_estimated_and_true_attitudes(rows: pd.DataFrame) -> None:
    """``q_true_*`` is the scenario's truth; a boresight method's ``q_est_*`` is the smallest
    rotation carrying its boresight to body z (its yaw a convention) and gives back its
    pointing error; a filter's gives back its yaw error."""
    world = GeoWorld.model_validate({k: SETTING[k] for k in GeoWorld.model_fields})
    scenario = build_geo_snr_scenario(world, manoeuvre=True)
    z = np.array([0.0, 0.0, 1.0])
    for method, frame in rows.groupby("method"):
        true = frame[[f"q_true_{c}" for c in "xyzw"]].to_numpy()
        np.testing.assert_array_equal(true, scenario.truth.as_quat())
        valid = frame["valid"].to_numpy()
        assert np.isnan(frame.loc[~valid, "q_est_x"]).all()
        frame, true = frame[valid], true[valid]
        estimate = Rotation.from_quat(frame[[f"q_est_{c}" for c in "xyzw"]].to_numpy())
        truth = Rotation.from_quat(true)
        boresight = estimate.inv().apply(z)
        error = np.degrees(pointing_error(truth, boresight)[:, :2])
        np.testing.assert_allclose(error, frame[["err_x_deg", "err_y_deg"]], atol=1e-9)
        if method in ("cone", "lsq", "nlp"):
            pointing = Rotation.concatenate([attitude_pointing(b) for b in boresight])
            np.testing.assert_allclose((pointing * estimate.inv()).magnitude(), 0.0, atol=1e-12)
        else:
            yaw = np.degrees((estimate * truth.inv()).as_rotvec()[:, 2])
            np.testing.assert_allclose(yaw, frame["yaw_err_deg"], atol=1e-9)
    assert rows.loc[rows["valid"], "nees"].notna().all()
    assert (rows["nees_dof"] == 2).all()  # every method over the axes the SNRs see
    filters = rows[rows["method"] == "usque"]
    yaw = np.radians(filters["yaw_err_deg"]) / np.radians(filters["sigma_z_deg"])
    np.testing.assert_allclose(filters["yaw_nees"], yaw**2, rtol=1e-12)
    filters = rows[rows["method"].isin(["usque", "usque_detect", "fg_batch"])]
    assert (filters["n_stations"] == 3).all()
    lsq = rows[rows["method"] == "lsq"]
    np.testing.assert_array_equal(lsq["n_stations"], scenario.heard.sum(axis=1))


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
    """The report of one trial per manoeuvre setting: Table 3 beside the paper's, the
    stations, the bounds table equal to the summary, the restarts, integrity with the rows'
    NEES, the figure."""
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
        assert cells["yaw RMS"] == "n/a" and np.isnan(line["yaw_rms_deg"])
        assert np.isnan(line["yaw_mean_deg"])
        # through the manoeuvre
        flagged = line["method"] in ("usque", "fg_batch") and line["manoeuvre"]
        assert (line["valid_fraction"] < 1.0) if flagged else (line["valid_fraction"] == 1.0)
        assert line["total_rms_deg"] == pytest.approx(
            np.hypot(line["roll_rms_deg"], line["pitch_rms_deg"]), rel=1e-12
        )
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
    manoeuvred = {
        m: row(integrity, {"manoeuvre": "True", "method": m})["valid"]
        for m in ("usque", "fg_batch")
    }
    assert set(integrity["valid"]) == {"1.000", *manoeuvred.values()}
    assert all(valid < "1.000" for valid in manoeuvred.values())
    means = labelled.groupby(["manoeuvre", "method"])["nees"].mean()
    for (manoeuvre, method), mean in means.items():
        cells = row(integrity, {"manoeuvre": str(manoeuvre), "method": method})
        assert cells["mean NEES"] == f"{mean:.3g}"
    # every method's two-axis NEES is consistent (mean 2; measured 1.8-2.5)
    assert means.between(1.0, 4.0).all(), means
    stations = table(text, "Stations")
    assert stations["station"].tolist() == [s.name for s in TABLE2_STATIONS]
    assert stations["filter station"].tolist() == [
        str(s.name in SETTING["filter_stations"]) for s in TABLE2_STATIONS
    ]
    assert (tmp_path / "usque_3sigma.png").stat().st_size > 10_000


def test_los_study_recovers_the_lines_of_sight_as_the_noise_vanishes() -> None:
    """Figs. 2-3's study: the belt fit's line-of-sight errors scale with the SNR noise."""
    quiet_world = GeoWorld(receiver={"snr_sigma_db": 1e-6})
    quiet = los_geometry_study(123.0, np.random.default_rng(4), 2, world=quiet_world)
    noisy = los_geometry_study(123.0, np.random.default_rng(4), 2)
    assert [r.station for r in quiet] == [r.station for r in noisy]
    assert {r.station for r in quiet} <= {s.name for s in TABLE2_STATIONS} and len(quiet) >= 3
    for q, n in zip(quiet, noisy, strict=True):
        assert q.joint_rms_deg < 1e-6 and q.single_rms_deg < 1e-5
        assert n.joint_rms_deg > 1e3 * q.joint_rms_deg
