"""Report of ``geo-snr-stations``: Pimienta-Penalver and Crassidis Table 3 (M2M4) beside
ours, the boresight error with perturbed RF parameters (Fig. 6), roll and pitch beside
their bounds, the manoeuvre detection, integrity and the filters' errors (Figs. 9-10).

Column meanings: :mod:`attopt.experiments.geo_snr_stations.experiment`; the
modelling (yaw unobservable from SNRs, rate input, restart): ``docs/geo.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from attopt.experiments.experiment import ReportContext
from attopt.experiments.geo_snr_stations.scenario import (
    MANOEUVRE_START_S,
    START_UTC,
    build_geo_snr_scenario,
)
from attopt.experiments.reporting.figures import error_figure, image_links, save_figure
from attopt.experiments.reporting.integrity import NOT_AVAILABLE, integrity_section
from attopt.experiments.reporting.paper_values import paper_label, paper_table, paper_values
from attopt.experiments.reporting.tables import (
    cell,
    document,
    made_by,
    markdown_table,
    section,
    with_paper,
)
from attopt.solvers.geo.boresight import rf_sensitivity
from attopt.solvers.geo.m2m4 import snr_table

PACKAGE = "attopt.experiments.geo_snr_stations"
TABLE3_SAMPLES, TABLE3_RECORDS, TABLE3_SEED = 1024, 300, 0
POWER_FACTORS = (0.95, 1.0, 1.05)
DIAMETER_OFFSETS_M = (-0.2, 0.0, 0.2)
METHOD_ORDER = ("cone", "lsq", "nlp", "usque", "usque_detect", "fg_batch")
FIGURE_METHODS = ("usque", "usque_detect")
KEYS = ["manoeuvre", "method"]


def table3_section() -> str:
    """M2M4 on simulated QPSK records beside Table 3."""
    paper = paper_table(PACKAGE, "table3")
    true = paper.columns[0]
    table = snr_table(
        np.random.default_rng(TABLE3_SEED), TABLE3_SAMPLES, TABLE3_RECORDS, true_db=paper[true]
    )
    ours = pd.DataFrame(
        {
            true: table.true_db,
            "ours mean (dB)": table.mean_db,
            "ours std (dB)": table.std_db,
            "invalid fraction": table.invalid_fraction,
        }
    )
    label = paper_label(PACKAGE, "table3")
    caption = (
        f"M2M4 on QPSK in complex AWGN, {TABLE3_SAMPLES} samples, {TABLE3_RECORDS} records per "
        f"SNR (`snr_table(default_rng({TABLE3_SEED}), {TABLE3_SAMPLES}, {TABLE3_RECORDS})`); "
        "means of the valid estimates."
    )
    table = with_paper(ours, paper, [true], label)
    table = markdown_table(table, {true: "g"}, spec=".3f")
    return section(f"{label}: M2M4 SNR estimator", caption, table)


def sensitivity_section(parameters: Mapping[str, Any]) -> str:
    """Boresight error at t = 0 with noise-free SNRs inverted with wrong RF parameters."""
    exact = paper_values(PACKAGE)["rf_parameters"]
    powers = [exact["power_w"] * f for f in POWER_FACTORS]
    diameters = [exact["diameter_m"] + d for d in DIAMETER_OFFSETS_M]
    scenario = build_geo_snr_scenario(parameters["duration_s"], parameters["step_s"])
    heard = np.flatnonzero(scenario.heard[0])
    lines = []
    for method in ("cone_intersection", "least_squares"):
        result = rf_sensitivity(
            scenario.truth[0],
            scenario.satellite_eci_km[0],
            scenario.stations_eci_km[0, heard],
            scenario.stations_up_eci[0, heard],
            powers,
            diameters,
            method=method,
        )
        for power, errors in zip(powers, np.degrees(result.error_rad), strict=True):
            cells = {f"D = {d:g} m": e for d, e in zip(diameters, errors, strict=True)}
            lines.append({"method": method, "P_t (kW)": power / 1e3} | cells)
    caption = (
        "t = 0, noise-free SNRs of the true link at "
        f"{', '.join(scenario.stations[i].name for i in heard)}, inverted assuming the (P_t, "
        f"D) below; boresight error in deg (exact: P_t = {exact['power_w'] / 1e3:g} kW, D = "
        f"{exact['diameter_m']:g} m, {paper_label(PACKAGE, 'rf_parameters')}; "
        "`solvers.geo.boresight.rf_sensitivity`)."
    )
    return section(
        "Boresight error with perturbed RF parameters (Pimienta-Penalver and Crassidis Fig. 6)",
        caption,
        markdown_table(pd.DataFrame(lines), {"P_t (kW)": "g"}, spec=".4f"),
    )


def bounds_section(summary: pd.DataFrame, command: str) -> str:
    """Per manoeuvre setting and method: roll and pitch RMS beside their bounds, filter yaw."""
    order = summary["method"].map({m: i for i, m in enumerate(METHOD_ORDER)})
    rows = summary.assign(order=order).sort_values(["manoeuvre", "order"])
    table = pd.DataFrame(
        {
            "manoeuvre": rows["manoeuvre"].to_numpy(),
            "method": rows["method"].to_numpy(),
            "valid": rows["valid_fraction"].to_numpy(),
            "roll RMS": rows["roll_rms_deg"].to_numpy(),
            "roll bound": rows["roll_bound_deg"].to_numpy(),
            "pitch RMS": rows["pitch_rms_deg"].to_numpy(),
            "pitch bound": rows["pitch_bound_deg"].to_numpy(),
            "yaw RMS": [cell(v, ".2e", NOT_AVAILABLE) for v in rows["yaw_rms_deg"]],
            "filter yaw RMS": rows["filter_yaw_rms_deg"].to_numpy(),
            "yaw inside 3 sigma": rows["yaw_inside_3sigma"].to_numpy(),
        }
    )
    caption = (
        "Pointing (boresight) error about body x (roll) and y (pitch), deg, RMS over the epochs "
        "of all trials. Bound: the filters' and smoother's own sigma; for cone, lsq and nlp the "
        "Cramer-Rao bound of their stations' SNRs. Yaw about the boresight is unobservable from "
        f"SNRs ({NOT_AVAILABLE}: the rows carry no yaw error); the filters' yaw RMS and the "
        "share of epochs with it inside 3 sigma are for the record only." + made_by(command)
    )
    formats = {"valid": ".3f", "filter yaw RMS": ".2f", "yaw inside 3 sigma": ".2f"}
    return section(
        "Roll and pitch beside the bound", caption, markdown_table(table, formats, spec=".2e")
    )


def detection_section(rows: pd.DataFrame, parameters: Mapping[str, Any], command: str) -> str:
    """Restart times of the detecting USQUE per trial."""
    detect = rows[rows["method"] == "usque_detect"]
    lines = []
    for (manoeuvre, trial), frame in detect.groupby(["manoeuvre", "trial_index"]):
        times = frame.loc[frame["detected"].astype(bool), "t_s"].to_numpy()
        after = times[times >= MANOEUVRE_START_S]
        lines.append(
            {
                "manoeuvre": manoeuvre,
                "trial": trial,
                "restarts at t (s)": ", ".join(f"{t:g}" for t in times) or "none",
                "first delay after the start (s)": (
                    after[0] - MANOEUVRE_START_S if manoeuvre and after.size else np.nan
                ),
            }
        )
    caption = (
        "Windowed chi-square test on USQUE's NIS: window "
        f"{parameters['detection_window_s']:g} s (at least 3 epochs), false-alarm probability "
        f"{parameters['false_alarm']:g} per window, epochs every {parameters['step_s']:g} s; "
        f"the manoeuvre (when on) starts at {MANOEUVRE_START_S:g} s." + made_by(command)
    )
    table = markdown_table(pd.DataFrame(lines), spec="g")
    return section("Manoeuvre detection", caption, table)


def figure_section(ctx: ReportContext) -> str:
    """USQUE's errors with +/-3 sigma, with and without detection (Figs. 9-10)."""
    first = ctx.rows[ctx.rows["trial_index"] == ctx.rows["trial_index"].min()]
    panels = list(first[first["method"].isin(FIGURE_METHODS)].groupby(KEYS))
    figure, axes = plt.subplots(
        3, len(panels), figsize=(4.5 * len(panels), 7), sharex=True, squeeze=False
    )
    for column, ((manoeuvre, method), frame) in enumerate(panels):
        error_figure(
            {method: frame},
            f"{method}, manoeuvre={manoeuvre}",
            values=("err_x_deg", "err_y_deg", "yaw_err_deg"),
            time="t_s",
            names=("roll (x)", "pitch (y)", "yaw (z), unobservable"),
            xlabel=f"t (s) from {START_UTC} UTC",
            ax=axes[:, column],
        )
        if manoeuvre:
            for axis in axes[:, column]:
                axis.axvline(MANOEUVRE_START_S, color="0.5", ls="--", lw=0.7)
    name = save_figure(figure, ctx.out_dir, "usque_3sigma.png")
    return section(
        "USQUE errors and 3-sigma bounds (Pimienta-Penalver and Crassidis Figs. 9-10)",
        "First trial of each setting." + made_by(ctx.command),
        image_links([name]),
    )


def report(ctx: ReportContext) -> str:
    """The sections of the module docstring, as markdown."""
    return document(
        [
            table3_section(),
            sensitivity_section(ctx.parameters),
            bounds_section(ctx.summary, ctx.command),
            detection_section(ctx.rows, ctx.parameters, ctx.command),
            integrity_section(ctx.rows, KEYS, ctx.command),
            figure_section(ctx),
        ]
    )
