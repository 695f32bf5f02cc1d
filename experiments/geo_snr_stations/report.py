"""Markdown report of ``geo-snr-stations`` (seed 004; issue 8 sec. 4).

Sections: Table 3 (M2M4, :func:`attopt.solvers.geo.m2m4.snr_table`) beside the
seed's values; the boresight error with exact and perturbed RF parameters
(Fig. 6, :func:`attopt.solvers.geo.boresight.rf_sensitivity`); each method's
roll/pitch RMS with its bound and the yaw (unobservable) line; the manoeuvre
detection result; the filters' errors with 3-sigma bounds (Figs. 9-10,
``usque_3sigma.png``).  Column meanings: :mod:`attopt.experiments.geo_snr_stations.experiment`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from attopt.experiments.experiment import ReportContext
from attopt.experiments.geo_snr_stations.scenario import (
    MANOEUVRE_START_S,
    START_UTC,
    build_geo_snr_scenario,
)
from attopt.solvers.geo.boresight import rf_sensitivity
from attopt.solvers.geo.m2m4 import snr_table

TABLE3_SEED = {0.0: 0.02, 2.0: 2.025, 4.0: 4.034, 6.0: 5.98, 8.0: 7.99, 10.0: 10.04}
"""Seed 004 Table 3: mean M2M4 estimate (dB) at each true SNR."""
TABLE3_SAMPLES, TABLE3_RECORDS = 1024, 300
POWERS_W = (11.4e3, 12.0e3, 12.6e3)
DIAMETERS_M = (11.8, 12.0, 12.2)
METHOD_ORDER = ("cone", "lsq", "nlp", "usque", "usque_detect", "fg_batch")
FIGURE_METHODS = ("usque", "usque_detect")


def _table3() -> list[str]:
    table = snr_table(np.random.default_rng(0), TABLE3_SAMPLES, TABLE3_RECORDS)
    lines = [
        "## Table 3: M2M4 SNR estimator",
        "",
        f"QPSK in complex AWGN, {TABLE3_SAMPLES} samples, {TABLE3_RECORDS} records per SNR, "
        "seed 0 (means of the valid estimates).",
        "",
        "| true SNR (dB) | seed 004 | ours mean | ours std | invalid fraction |",
        "|---|---|---|---|---|",
    ]
    for true, mean, std, bad in zip(
        table.true_db, table.mean_db, table.std_db, table.invalid_fraction, strict=True
    ):
        seed = TABLE3_SEED.get(float(true))
        seed_text = "" if seed is None else f"{seed:g}"
        lines.append(f"| {true:g} | {seed_text} | {mean:.3f} | {std:.3f} | {bad:.3f} |")
    return lines


def _sensitivity(parameters: Mapping[str, Any]) -> list[str]:
    scenario = build_geo_snr_scenario(parameters["duration_s"], parameters["step_s"])
    heard = np.flatnonzero(scenario.heard[0])
    names = ", ".join(scenario.stations[i].name for i in heard)
    lines = [
        "",
        "## Boresight error with exact and perturbed RF parameters (Fig. 6)",
        "",
        f"t = 0, noise-free SNRs of the true link at {names}, inverted assuming the (P_t, D) "
        "below; boresight error in deg (exact parameters: P_t = 12 kW, D = 12 m).",
        "",
        "| method | P_t (kW) | " + " | ".join(f"D = {d:g} m" for d in DIAMETERS_M) + " |",
        "|---|---|" + "---|" * len(DIAMETERS_M),
    ]
    for method in ("cone_intersection", "least_squares"):
        result = rf_sensitivity(
            scenario.truth[0],
            scenario.satellite_eci_km[0],
            scenario.stations_eci_km[0, heard],
            scenario.stations_up_eci[0, heard],
            POWERS_W,
            DIAMETERS_M,
            method=method,
        )
        for power, errors in zip(POWERS_W, np.degrees(result.error_rad), strict=True):
            cells = " | ".join(f"{e:.4f}" for e in errors)
            lines.append(f"| {method} | {power / 1e3:g} | {cells} |")
    return lines


def _methods(summary: pd.DataFrame) -> list[str]:
    lines = [
        "",
        "## Roll and pitch: RMS error beside the bound",
        "",
        "Pointing error (boresight) about body x (roll) and y (pitch), deg. Bound: the",
        "filters' and smoother's own sigma (RMS over epochs); for cone, lsq and nlp the",
        "Cramer-Rao bound of their stations' SNRs. Yaw about the boresight is unobservable",
        "from SNRs (not an error of the methods): the filters carry it with a large sigma;",
        "their yaw RMS and the share of epochs with the yaw error inside 3 sigma are listed",
        "for the record only.",
        "",
        "| manoeuvre | method | valid | roll RMS | roll bound | pitch RMS | pitch bound "
        "| yaw | filter yaw RMS | yaw inside 3 sigma |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = summary["method"].map({m: i for i, m in enumerate(METHOD_ORDER)})
    rows = summary.assign(order=order).sort_values(["manoeuvre", "order"])
    for _, r in rows.iterrows():
        yaw = "" if pd.isna(r["filter_yaw_rms_deg"]) else f"{r['filter_yaw_rms_deg']:.2f}"
        inside = "" if pd.isna(r["yaw_inside_3sigma"]) else f"{r['yaw_inside_3sigma']:.2f}"
        lines.append(
            f"| {r['manoeuvre']} | {r['method']} | {r['valid_fraction']:.3f} "
            f"| {r['roll_rms_deg']:.2e} | {r['roll_bound_deg']:.2e} "
            f"| {r['pitch_rms_deg']:.2e} | {r['pitch_bound_deg']:.2e} "
            f"| unobservable | {yaw} | {inside} |"
        )
    return lines


def _detection(rows: pd.DataFrame, parameters: Mapping[str, Any]) -> list[str]:
    detect = rows[rows["method"] == "usque_detect"]
    lines = [
        "",
        "## Manoeuvre detection",
        "",
        "Windowed chi-square test on USQUE's NIS: window "
        f"{parameters['detection_window_s']:g} s (at least 3 epochs), false-alarm probability "
        f"{parameters['false_alarm']:g} per window, epoch step {parameters['step_s']:g} s; "
        f"manoeuvre (when on) from {MANOEUVRE_START_S:g} s. "
        "Restart times per trial (s):",
        "",
        "| manoeuvre | trial | restarts at t (s) | first delay after the start (s) |",
        "|---|---|---|---|",
    ]
    for (manoeuvre, trial), frame in detect.groupby(["manoeuvre", "trial_index"]):
        times = frame.loc[frame["detected"].astype(bool), "t_s"].to_numpy()
        after = times[times >= MANOEUVRE_START_S]
        delay = f"{after[0] - MANOEUVRE_START_S:g}" if manoeuvre and after.size else ""
        listed = ", ".join(f"{t:g}" for t in times) or "none"
        lines.append(f"| {manoeuvre} | {trial} | {listed} | {delay} |")
    return lines


def _figure(ctx: ReportContext) -> list[str]:
    first = ctx.rows[ctx.rows["trial_index"] == ctx.rows["trial_index"].min()]
    first = first[first["method"].isin(FIGURE_METHODS)]
    panels = list(first.groupby(["manoeuvre", "method"]))
    fig, axes = plt.subplots(3, len(panels), figsize=(4.5 * len(panels), 7), squeeze=False)
    for col, ((manoeuvre, method), frame) in enumerate(panels):
        series = (
            ("err_x_deg", "sigma_x_deg", "roll (x)"),
            ("err_y_deg", "sigma_y_deg", "pitch (y)"),
        )
        series += (("yaw_err_deg", "sigma_z_deg", "yaw (z), unobservable"),)
        for ax, (err, sigma, label) in zip(axes[:, col], series, strict=True):
            ax.plot(frame["t_s"], frame[err], lw=0.7, label="error")
            ax.plot(frame["t_s"], 3 * frame[sigma], "r", lw=0.7, label="+/- 3 sigma")
            ax.plot(frame["t_s"], -3 * frame[sigma], "r", lw=0.7)
            ax.set_ylabel(f"{label} [deg]", fontsize=8)
            if manoeuvre:
                ax.axvline(MANOEUVRE_START_S, color="0.6", ls="--", lw=0.7)
        axes[0, col].set_title(f"{method}, manoeuvre={manoeuvre}", fontsize=9)
        axes[-1, col].set_xlabel(f"t [s] from {START_UTC} UTC", fontsize=8)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    name = "usque_3sigma.png"
    fig.savefig(ctx.out_dir / name, dpi=110)
    plt.close(fig)
    return ["", "## USQUE errors and 3-sigma bounds (Figs. 9-10), trial 0", "", f"![]({name})"]


def report(ctx: ReportContext) -> str:
    """The sections of the module docstring, as markdown."""
    parameters = ctx.parameters
    lines = _table3() + _sensitivity(parameters) + _methods(ctx.summary)
    lines += _detection(ctx.rows, parameters) + _figure(ctx)
    return "\n".join(lines) + "\n"
