"""Scenario and experiment ``doa-ground`` (Yang et al. 2014 secs. 4.2, 6)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from attopt.experiments.doa_ground.experiment import EXPERIMENT, grid
from attopt.experiments.doa_ground.parameters import DoaScenario, RigidBodyTruth
from attopt.experiments.doa_ground.scenario import build_geometry, coverage
from attopt.experiments.sweep.seeding import trial_seed
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.rigid_body import YANG2014_INERTIA

COARSE = DoaScenario(step_s=10.0)
"""The whole (default, 5000 s) pass at a coarse step keeps the geometry cheap."""


def test_a_station_is_visible_over_the_pass_within_the_array_cone() -> None:
    """At least one station above 10 deg until the last pass ends; theta stays near 62 deg."""
    geometry = build_geometry(COARSE)
    last_pass_end = geometry.t[np.flatnonzero(coverage(geometry))[-1]]
    assert last_pass_end > 4800.0
    assert np.all(coverage(geometry)[geometry.t <= last_pass_end] >= 1)
    assert np.all(geometry.visible.any(axis=0))  # every station is seen
    assert np.all(geometry.elevation_deg[geometry.visible] >= COARSE.min_elevation_deg)
    theta = np.degrees(geometry.doa[..., 0][geometry.visible])
    assert theta.max() < 62.0 + 5.0  # the 62 deg of sec. 4.2 plus the attitude's wander


def test_doas_are_the_measurement_model_at_the_truth() -> None:
    """The scenario's true DOAs are eqs. 13-16 (``DoaMeasurement``) at the true attitude."""
    geometry = build_geometry(COARSE)
    for k in (0, 150, 300):
        visible = geometry.visible[k]
        doa = geometry.doa[k, visible]
        measurement = DoaMeasurement(
            doa, np.tile(1e-6 * np.eye(2), (len(doa), 1, 1)), geometry.line_of_sight_km[k, visible]
        )
        predicted, _ = measurement.predict(geometry.truth[k])
        np.testing.assert_allclose(measurement.innovation(predicted[0]), 0.0, atol=1e-9)


def test_torque_free_dynamics_conserve_inertial_angular_momentum() -> None:
    """Eq. 23 without torque: ``A_bi^T (I omega + h)`` is constant over the pass."""
    geometry = build_geometry(COARSE)
    body_momentum = geometry.rate @ YANG2014_INERTIA.T + RigidBodyTruth().wheel_momentum
    inertial = (geometry.truth * geometry.eci_to_orbit).inv().apply(body_momentum)
    drift = np.abs(inertial - inertial[0]).max()
    assert drift < 1e-9 * np.linalg.norm(inertial[0])
    # and the body does move: the rate changes direction in the body frame
    assert np.degrees(np.abs(geometry.rate - geometry.rate[0]).max()) > 1e-3


def test_quick_trial_is_reproducible() -> None:
    """The same seed gives the same rows; another seed other DOA errors."""
    parameters = {
        **EXPERIMENT.parameters,
        "duration_s": 60.0,
        "settle_s": 30.0,
        "table1_snr_db": [0.0],
        "table2_snapshots": [],
    }
    (setting,) = grid(parameters)
    first = EXPERIMENT.trial(setting, np.random.SeedSequence(7))
    again = EXPERIMENT.trial(setting, np.random.SeedSequence(7))
    other = EXPERIMENT.trial(setting, np.random.SeedSequence(8))
    # runtime_s is the only column that is not reproducible
    pd.testing.assert_frame_equal(first.drop(columns="runtime_s"), again.drop(columns="runtime_s"))
    assert set(first["method"]) == {
        "ekf_yang2014_q1e-09",
        "ekf_yang2014_q1e-12",
        "rts_yang2014_q1e-09",
        "rts_yang2014_q1e-12",
        "bls_yang2014",
        "wahba",
        "music",
        "mekf",
        "fg_batch",
    }
    music = first[first["method"] == "music"].iloc[0]
    assert music["doa_accepted"] == music["doa_count"] > 0
    other_music = other[other["method"] == "music"].iloc[0]
    assert music["doa_theta_mse_deg2"] != other_music["doa_theta_mse_deg2"]


def test_gyro_aided_rows_reach_the_posterior_bound() -> None:
    """The MEKF and the smoother on the unit vectors plus a MEMS gyro (5 min at
    0 dB, L = 100, from the EKF's 98 deg initial error): valid, the smoother at
    most the MEKF's RMS and within a factor of 2 of the posterior bound the rows
    carry (one short trial); each RTS pass below its EKF, with the bounds ordered; the
    batch least squares below the low-Q RTS (measured: 0.55 of its CRB)."""
    parameters = {
        **EXPERIMENT.parameters,
        "duration_s": 300.0,
        "settle_s": 100.0,
        "table1_snr_db": [0.0],
        "table2_snapshots": [],
    }
    (setting,) = grid(parameters)
    rows = EXPERIMENT.trial(setting, np.random.SeedSequence(3))
    settled = rows[rows["phase"] == "settled"]

    def rms(method: str, column: str = "err_{}_deg") -> float:
        """Errors over the valid settled rows of the gyro-aided estimators, and over all the
        settled rows of Yang et al. 2014's (300 s from their 98 deg start is too short for
        the start check to confirm them, so the rows show the unchecked runs' errors:
        this compares the paper's estimators, not their integrity); bounds over all."""
        chosen = settled[settled["method"] == method]
        if method == "fg_batch":
            assert chosen["valid"].mean() >= 0.8, method
            if column.startswith("err"):
                chosen = chosen[chosen["valid"]]
        return float(np.sqrt(sum((chosen[column.format(a)] ** 2).mean() for a in "xyz")))

    # one station in view: no epoch's measurement determines every axis, so no single
    # frame checks the MEKF's start from the prior's 60 deg sigmas, and it is flagged
    mekf = rows[rows["method"] == "mekf"]
    assert set(mekf["reason"].str.split(" wider").str[0]) <= {
        "converging: started from a prior",
        "attitude not determined: 1-sigma above 15 deg",
    }
    assert 0.5 < rms("fg_batch") / rms("fg_batch", "pbound_{}_deg") < 2.0
    for q in ("1e-09", "1e-12"):  # the RTS pass improves on its EKF, and the bound on both
        ekf, rts = f"ekf_yang2014_q{q}", f"rts_yang2014_q{q}"
        assert rms(rts) < rms(ekf)
        assert rms(rts, "pbound_{}_deg") < rms(ekf, "pbound_{}_deg")
        assert rms(rts, "crb_{}_deg") < rms(ekf, "crb_{}_deg") < rms(ekf, "pbound_{}_deg")
    # the batch least squares: below the low-Q RTS, its bound the RTS's Q = 0 bound
    assert rms("bls_yang2014") < rms("rts_yang2014_q1e-12")
    assert rms("bls_yang2014", "pbound_{}_deg") == rms("rts_yang2014_q1e-12", "crb_{}_deg")


def test_gyro_rows_run_in_the_first_filter_trials_only() -> None:
    """``filter_trials`` bounds the costly rows by trial index, whatever the engine."""
    parameters = {
        **EXPERIMENT.parameters,
        "duration_s": 30.0,
        "settle_s": 10.0,
        "table1_snr_db": [0.0],
        "table2_snapshots": [],
        "filter_trials": 1,
    }
    (setting,) = grid(parameters)
    first = EXPERIMENT.trial(setting, trial_seed(0, 0, 0))
    second = EXPERIMENT.trial(setting, trial_seed(0, 0, 1))
    assert {"bls_yang2014", "mekf", "fg_batch"} <= set(first["method"])
    assert not {"bls_yang2014", "mekf", "fg_batch"} & set(second["method"])
    assert {"ekf_yang2014_q1e-09", "rts_yang2014_q1e-12", "wahba"} <= set(second["method"])


def test_single_frame_rows_do_not_use_doas_below_musics_threshold() -> None:
    """The first stretch with two stations in view (588-612 s): at 0 dB, L = 100 (output
    SNR 1200) the ``wahba`` rows there are valid; at L = 10 (output SNR 120) every one is
    flagged below MUSIC's threshold, while the DOAs stay accepted for the other rows."""
    parameters = {
        **EXPERIMENT.parameters,
        "duration_s": 620.0,
        "settle_s": 300.0,
        "row_step_s": 1.0,
        "table1_snr_db": [0.0],
        "table2_snapshots": [10],
        "filter_trials": 0,
    }
    rows = [EXPERIMENT.trial(s, np.random.SeedSequence(3)) for s in grid(parameters)]
    stretch = [r[(r["method"] == "wahba") & r["t_s"].between(588.0, 611.0)] for r in rows]
    high, single = stretch
    assert len(high) == len(single) >= 20
    assert high["valid"].mean() > 0.9
    assert not single["valid"].any()
    assert single["reason"].str.startswith("below MUSIC's threshold").all()
    music = rows[1][rows[1]["method"] == "music"].iloc[0]
    assert music["doa_accepted"] > 0.99 * music["doa_count"]
