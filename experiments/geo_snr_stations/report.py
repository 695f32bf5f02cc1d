"""Report of ``geo-snr-stations``: Pimienta-Penalver and Crassidis Table 3 (M2M4) beside
ours, the configured stations, the boresight error with perturbed RF parameters (Fig. 6),
roll and pitch beside their bounds, the manoeuvre detection, integrity and the filters'
errors (Figs. 9-10).  Every table follows the configured set-up (its stations, link,
manoeuvre, methods and filters).

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
from attopt.experiments.geo_snr_stations.parameters import GeoWorld
from attopt.experiments.geo_snr_stations.scenario import build_geo_snr_scenario
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
from attopt.formulations.errors import AttoptError
from attopt.solvers.geo.boresight import MIN_STATIONS, rf_sensitivity
from attopt.solvers.geo.m2m4 import snr_table

PACKAGE = "attopt.experiments.geo_snr_stations"
TABLE3_SAMPLES, TABLE3_RECORDS, TABLE3_SEED = 1024, 300, 0
POWER_FACTORS = (0.95, 1.0, 1.05)
DIAMETER_OFFSETS_M = (-0.2, 0.0, 0.2)
FIGURE_METHODS = ("usque", "usque_detect")
"""The filters of the figure when configured: the paper's UKF without and with detection."""
KEYS = ["manoeuvre", "method"]


def world_of(parameters: Mapping[str, Any]) -> GeoWorld:
    """The simulated world of a run's parameters (or of one setting's)."""
    return GeoWorld.model_validate({name: parameters[name] for name in GeoWorld.model_fields})


def stations_section(parameters: Mapping[str, Any]) -> str:
    """The configured stations: position, whether the filters use them, and what they hear
    of the pass without the manoeuvre (noise-free)."""
    world = world_of(parameters)
    scenario = build_geo_snr_scenario(world)
    filters = set(parameters.get("filter_stations", ()))
    table = pd.DataFrame(
        {
            "station": scenario.station_names,
            "latitude (deg)": [s.latitude_deg for s in world.stations],
            "longitude (deg)": [s.longitude_deg for s in world.stations],
            "height (m)": [s.height_m for s in world.stations],
            "filter station": [name in filters for name in scenario.station_names],
            "elevation at start (deg)": np.degrees(scenario.elevation_rad[0]),
            "heard (share of epochs)": scenario.heard.mean(axis=0),
            "SNR at start (dB)": scenario.true_snr_db[0],
            "SNR at end (dB)": scenario.true_snr_db[-1],
        }
    )
    caption = (
        f"{len(world.stations)} stations; noise-free SNRs (eq. 7) of the pass without the "
        f"manoeuvre, epochs every {world.step_s:g} s over {world.duration_s:g} s from "
        f"{world.start_utc} UTC. A station hears the broadcaster above its horizon with a "
        f"noise-free SNR of at least {world.receiver.detection_threshold_db:g} dB; "
        f"{NOT_AVAILABLE}: outside the main lobe."
    )
    formats = {"latitude (deg)": "g", "longitude (deg)": "g", "height (m)": "g"}
    return section(
        "Stations", caption, markdown_table(table, formats, spec=".3g", missing=NOT_AVAILABLE)
    )


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
    title = "Boresight error with perturbed RF parameters (Pimienta-Penalver and Crassidis Fig. 6)"
    scenario = build_geo_snr_scenario(world_of(parameters))
    link = scenario.link
    powers = [link.transmit_power_w * f for f in POWER_FACTORS]
    diameters = [link.dish_diameter_m + d for d in DIAMETER_OFFSETS_M]
    heard = np.flatnonzero(scenario.heard[0])
    if heard.size < MIN_STATIONS:
        return section(
            title, f"Not computed: {heard.size} station(s) hear the broadcaster at t = 0."
        )
    lines = []
    for method in ("cone_intersection", "least_squares"):
        try:
            result = rf_sensitivity(
                scenario.truth[0],
                scenario.satellite_eci_km[0],
                scenario.stations_eci_km[0, heard],
                scenario.stations_up_eci[0, heard],
                powers,
                diameters,
                link,
                method=method,
            )
        except AttoptError as error:
            lines.append({"method": method, "P_t (kW)": np.nan, "failed": str(error)})
            continue
        for power, errors in zip(powers, np.degrees(result.error_rad), strict=True):
            cells = {f"D = {d:g} m": e for d, e in zip(diameters, errors, strict=True)}
            lines.append({"method": method, "P_t (kW)": power / 1e3} | cells)
    paper = paper_values(PACKAGE)["rf_parameters"]
    caption = (
        "t = 0, noise-free SNRs of the configured link at "
        f"{', '.join(scenario.stations[i].name for i in heard)}, inverted assuming the (P_t, "
        f"D) below; boresight error in deg (exact: the configured P_t = "
        f"{link.transmit_power_w / 1e3:g} kW, D = {link.dish_diameter_m:g} m; "
        f"{paper_label(PACKAGE, 'rf_parameters')}: {paper['power_w'] / 1e3:g} kW, "
        f"{paper['diameter_m']:g} m; `solvers.geo.boresight.rf_sensitivity`)."
    )
    return section(
        title, caption, markdown_table(pd.DataFrame(lines), {"P_t (kW)": "g"}, spec=".4f")
    )


def bounds_section(summary: pd.DataFrame, parameters: Mapping[str, Any], command: str) -> str:
    """Per manoeuvre setting and method: roll and pitch RMS beside their bounds, filter yaw
    (methods in their configured order)."""
    configured = [*parameters["methods"], *parameters["filters"]]
    order = summary["method"].map({m: i for i, m in enumerate(configured)})
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
        "Cramer-Rao bound of their stations' SNRs (the one-step solvers': lsq's). Yaw about the "
        "boresight is unobservable from "
        f"SNRs ({NOT_AVAILABLE}: the rows carry no yaw error); the filters' yaw RMS and the "
        "share of epochs with it inside 3 sigma are for the record only." + made_by(command)
    )
    formats = {"valid": ".3f", "filter yaw RMS": ".2f", "yaw inside 3 sigma": ".2f"}
    return section(
        "Roll and pitch beside the bound", caption, markdown_table(table, formats, spec=".2e")
    )


def detection_section(rows: pd.DataFrame, parameters: Mapping[str, Any], command: str) -> str:
    """Restart times of the detecting USQUE per trial (none without ``usque_detect`` rows)."""
    detect = rows[rows["method"] == "usque_detect"]
    if detect.empty:
        return ""
    start = world_of(parameters).attitude.manoeuvre.start_s
    lines = []
    for (manoeuvre, trial), frame in detect.groupby(["manoeuvre", "trial_index"]):
        times = frame.loc[frame["detected"].astype(bool), "t_s"].to_numpy()
        after = times[times >= start]
        lines.append(
            {
                "manoeuvre": manoeuvre,
                "trial": trial,
                "restarts at t (s)": ", ".join(f"{t:g}" for t in times) or "none",
                "first delay after the start (s)": (
                    after[0] - start if manoeuvre and after.size else np.nan
                ),
            }
        )
    caption = (
        "Windowed chi-square test on USQUE's NIS: window "
        f"{parameters['detection_window_s']:g} s (at least 3 epochs), false-alarm probability "
        f"{parameters['false_alarm']:g} per window, epochs every {parameters['step_s']:g} s; "
        f"the manoeuvre (when on) starts at {start:g} s." + made_by(command)
    )
    table = markdown_table(pd.DataFrame(lines), spec="g")
    return section("Manoeuvre detection", caption, table)


def figure_section(ctx: ReportContext) -> str:
    """USQUE's errors with +/-3 sigma, with and without detection (Figs. 9-10), those of
    :data:`FIGURE_METHODS` that ran."""
    first = ctx.rows[ctx.rows["trial_index"] == ctx.rows["trial_index"].min()]
    panels = list(first[first["method"].isin(FIGURE_METHODS)].groupby(KEYS))
    if not panels:
        return ""
    world = world_of(ctx.parameters)
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
            xlabel=f"t (s) from {world.start_utc} UTC",
            ax=axes[:, column],
        )
        if manoeuvre:
            for axis in axes[:, column]:
                axis.axvline(world.attitude.manoeuvre.start_s, color="0.5", ls="--", lw=0.7)
    name = save_figure(figure, ctx.out_dir, "usque_3sigma.png")
    return section(
        "USQUE errors and 3-sigma bounds (Pimienta-Penalver and Crassidis Figs. 9-10)",
        "First trial of each setting." + made_by(ctx.command),
        image_links([name]),
    )


def integrity_note() -> str:
    """What the integrity table's NEES is here."""
    return (
        "The NEES of every method is over the two axes across the boresight (2 dof, mean 2 "
        "if consistent), the axes the SNRs see; rows are tested against the chi-square(2) "
        "quantile, 18.4. The filters' and smoothers' yaw comes from the prior carried by the "
        "assumed rates, which no SNR can check: after an unmodelled manoeuvre it is wrong by "
        "the manoeuvre's angle with nothing in the innovations to show it. It is therefore "
        "not part of the test, and its own check, the share of epochs with the yaw error "
        "inside 3 sigma, is in the table above."
    )


def report(ctx: ReportContext) -> str:
    """The sections of the module docstring, as markdown."""
    return document(
        [
            table3_section(),
            stations_section(ctx.parameters),
            sensitivity_section(ctx.parameters),
            bounds_section(ctx.summary, ctx.parameters, ctx.command),
            detection_section(ctx.rows, ctx.parameters, ctx.command),
            integrity_section(ctx.rows, KEYS, ctx.command) + "\n" + integrity_note() + "\n",
            figure_section(ctx),
        ]
    )
