"""Report of ``wahba-mag-sun``: Cilden Guler et al. 2017 Table 1 beside ours, the
gyro-aided filters through the eclipse, integrity and figures.

Tables only; what they compare and why the numbers differ from the paper's is
in ``docs/results.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from attopt.experiments.experiment import ReportContext
from attopt.experiments.reporting.figures import (
    error_figure,
    first_trial,
    image_links,
    save_figure,
)
from attopt.experiments.reporting.integrity import integrity_section
from attopt.experiments.reporting.paper_values import paper_label, paper_table, paper_values
from attopt.experiments.reporting.statistics import (
    AXES,
    error_summary,
    rms,
    rms_ratio,
    valid_mask,
)
from attopt.experiments.reporting.tables import (
    document,
    joined,
    made_by,
    markdown_table,
    section,
    with_paper,
)
from attopt.experiments.wahba_mag_sun.scenario import INTERVALS, eclipse_intervals

PACKAGE = "attopt.experiments.wahba_mag_sun"
KEYS = ["method", "interval"]
ANGLES = ("roll", "pitch", "yaw")
FIGURE_FILTERS = ("mekf", "rts")
"""Filters drawn in the filter figures (USQUE's curves coincide with the MEKF's)."""
SETTLE_S = 120.0
"""The filter figures fit their y axes to t >= this (the convergence from the prior is
off scale)."""
TIME = "t_s"


def _group_statistics(group: pd.DataFrame) -> pd.Series:
    valid = group[valid_mask(group)]
    out = error_summary(group)
    for name, axis in zip(ANGLES, AXES, strict=True):
        out[f"euler_{name}_rms"] = rms(valid[f"euler_{name}_err_deg"])
        out[f"max_3sigma_{axis}"] = 3.0 * valid[f"sigma_{axis}_deg"].max()
        if f"bias_err_{axis}_deg_h" in valid:
            out[f"bias_{axis}_rms"] = rms(valid[f"bias_err_{axis}_deg_h"])
    out["rms_crb"] = rms_ratio(valid, "bound")
    out["rms_pbound"] = rms_ratio(valid, "pbound") if "pbound_x_deg" in valid else np.nan
    out["nees_full"] = valid["nees_full"].mean() if "nees_full" in valid else np.nan
    return pd.Series(out)


def interval_statistics(rows: pd.DataFrame, methods: list[str]) -> pd.DataFrame:
    """Per method (in ``methods`` order) and interval: valid share and, over the valid rows,
    body-axis and Euler-difference RMS per axis, total RMS, RMS over the single-epoch CRB
    (``bound``) and over the pass's posterior bound (``pbound``), mean NEES (3 and 6),
    share inside 3 sigma, largest 3 sigma per axis and the gyro-bias error RMS."""
    chosen = rows[rows["method"].isin(methods)]
    table = chosen.groupby(KEYS).apply(_group_statistics, include_groups=False).reset_index()
    rank = {"method": {m: k for k, m in enumerate(methods)}}
    rank["interval"] = {i: k for k, i in enumerate(INTERVALS)}
    table = table.sort_values(KEYS, key=lambda column: column.map(rank[column.name]))
    return table.reset_index(drop=True)


def eclipse_spans(rows: pd.DataFrame, step_s: float) -> list[tuple[float, float]]:
    """``[start, end)`` of each eclipse in the rows of one setting (its runs of ``eclipse``
    epochs, :func:`~attopt.experiments.wahba_mag_sun.scenario.eclipse_intervals`)."""
    epochs = rows.drop_duplicates(TIME).sort_values(TIME)
    in_eclipse = (epochs["interval"] == "eclipse").to_numpy()
    return list(eclipse_intervals(epochs[TIME].to_numpy(dtype=float), in_eclipse, step_s))


def orbit_label(orbit: Mapping[str, Any]) -> str:
    """The configured orbit in a few words (its TLE's catalogue number, or the circular
    orbit's altitude, inclination and node time)."""
    if orbit["type"] == "tle":
        return f"TLE of catalogue number {orbit['line1'][2:7].strip()}"
    inclination = orbit["inclination_deg"]
    tilt = "Sun-synchronous" if inclination is None else f"{inclination:g} deg inclination"
    return f"circular {orbit['altitude_km']:g} km, {tilt}, ascending node at {orbit['ltan_h']:g} h"


def gyro_label(gyro: str | Mapping[str, Any]) -> str:
    """The configured gyro: its preset name, or its name and datasheet numbers."""
    if isinstance(gyro, str):
        return f"`{gyro}`"
    return (
        f"`{gyro['name']}` ({gyro['rate_hz']:g} Hz, angle random walk "
        f"{gyro['arw_deg_sqrt_h']:g} deg/h^(1/2), rate random walk "
        f"{gyro['rrw_deg_h_sqrt_h']:g} deg/h per h^(1/2), turn-on bias "
        f"{gyro['turn_on_bias_deg_h']:g} deg/h)"
    )


def window_label(eclipses: list[tuple[float, float]]) -> str:
    """The eclipses of the window for a caption."""
    if not eclipses:
        return "no eclipse in the window (every epoch no_eclipse)"
    spans = ", ".join(f"{start:.0f}-{end:.0f} s" for start, end in eclipses)
    return f"eclipse{'s' if len(eclipses) > 1 else ''} (cylindrical shadow) t = {spans}"


def table1_section(ctx: ReportContext, stats: pd.DataFrame) -> str:
    """Table 1 of Cilden Guler et al. 2017 beside the single-frame methods."""
    single = stats[stats["method"].isin(ctx.parameters["methods"])]
    paper = paper_table(PACKAGE, "table1")
    label = paper_label(PACKAGE, "table1")
    columns = [f"{a}" for a in ANGLES]
    paper = paper[KEYS].assign(**{"RMS roll / pitch / yaw": joined(paper, columns, ".2f", "nd")})
    ours = single[KEYS].assign(
        valid=single["valid_fraction"],
        **{
            "RMS roll / pitch / yaw": joined(single, [f"rms_{a}" for a in AXES]),
            "Euler-difference RMS roll / pitch / yaw": joined(
                single, [f"euler_{a}_rms" for a in ANGLES]
            ),
        },
    )
    table = with_paper(ours, paper, KEYS, label).assign(
        **{
            "RMS / CRB": single["rms_crb"].to_numpy(),
            "mean NEES": single["mean_nees"].to_numpy(),
            "inside 3 sigma": single["inside_3_sigma"].to_numpy(),
        }
    )
    p = ctx.parameters
    window = window_label(eclipse_spans(ctx.rows, float(p["step_s"])))
    stated = paper_values(PACKAGE)["eclipse"]
    caption = (
        "Single-frame methods per interval, over the valid epochs of all trials: body-axis RMS "
        "error and RMS of the 3-2-1 Euler-angle differences (deg; the paper tabulates the "
        "latter), total RMS over the RMS of the single-epoch Cramer-Rao bound, mean NEES (3 "
        "when consistent), share of epochs within 3 sigma on all axes. Orbit: "
        f"{orbit_label(p['orbit'])}, {p['duration_s']:g} s from {p['start_utc']} UTC; "
        f"{window}. The paper's columns are its own pass (TIMED, eclipse at "
        f"{stated['start_s']:.0f}-{stated['end_s']:.0f} s); nd: no data in the paper."
        + made_by(ctx.command)
    )
    formats = {"valid": ".3f", "RMS / CRB": ".3f", "mean NEES": ".3f", "inside 3 sigma": ".3f"}
    return section(f"{label} beside ours", caption, markdown_table(table, formats))


def filter_section(ctx: ReportContext, stats: pd.DataFrame, filters: list[str]) -> str:
    """The gyro-aided filters per interval, and their pass times."""
    chosen = stats[stats["method"].isin(filters)]
    table = chosen[KEYS].assign(
        valid=chosen["valid_fraction"],
        **{
            "RMS roll / pitch / yaw": joined(chosen, [f"rms_{a}" for a in AXES]),
            "total RMS": chosen["total_rms"],
            "RMS / CRB": chosen["rms_crb"],
            "RMS / posterior bound": chosen["rms_pbound"],
            "mean NEES (3)": chosen["mean_nees"],
            "mean NEES (6)": chosen["nees_full"],
            "inside 3 sigma": chosen["inside_3_sigma"],
            "max 3 sigma roll / pitch / yaw": joined(chosen, [f"max_3sigma_{a}" for a in AXES]),
            "bias error RMS x / y / z (deg/h)": joined(
                chosen, [f"bias_{a}_rms" for a in AXES], ".2f"
            ),
        },
    )
    p = ctx.parameters
    first = chosen["interval"].iloc[0] if len(chosen) else INTERVALS[0]
    caption = (
        f"Filters on the single-frame methods' vectors plus a simulated {gyro_label(p['gyro'])} "
        f"gyro, from an initial attitude error of {p['initial_sigma_deg']:g} deg per axis, over "
        f"the valid epochs of all trials (deg; {first} includes the convergence): RMS / CRB "
        "against the single-epoch Cramer-Rao bound (none in eclipse), RMS / posterior bound "
        "against the posterior Cramer-Rao bound of the pass (gyro and every vector), NEES of "
        "the attitude (3) and of attitude and bias (6), largest 3 sigma of the filter's own "
        "covariance, RMS gyro-bias error." + made_by(ctx.command)
    )
    formats = {c: ".3f" for c in table.columns if c not in KEYS}
    frame = ctx.rows[ctx.rows["method"].isin(filters)]
    passes = frame.groupby(["setting_index", "trial_index", "method"])["runtime_s"].first()
    mean = passes.groupby("method").mean().reindex(filters)
    duration = float(p["duration_s"])
    runtime = pd.DataFrame(
        {
            "filter": filters,
            "passes": passes.groupby("method").size().reindex(filters).to_numpy(),
            "runtime per pass (s)": mean.to_numpy(),
            "per hour of data (s)": mean.to_numpy() * 3600.0 / duration,
        }
    )
    runtime_caption = (
        f"Mean wall time of one {duration:.0f} s pass in the sweep's worker process (the RTS "
        "row includes the MEKF it smooths, fg_batch the passes it starts from)."
        + made_by(ctx.command)
    )
    return section(
        "Gyro-aided filters through the eclipse",
        caption,
        markdown_table(table, formats),
        runtime_caption,
        markdown_table(runtime, {"runtime per pass (s)": ".2f", "per hour of data (s)": ".2f"}),
    )


def figures(ctx: ReportContext, filters: list[str]) -> list[str]:
    """Per single-frame method its errors (first trial); the filters' attitude and bias errors."""
    rows = first_trial(ctx.rows)
    spans = [(*span, "eclipse") for span in eclipse_spans(rows, float(ctx.parameters["step_s"]))]
    xlabel = f"t (s) from {ctx.parameters['start_utc']} UTC"
    names = []
    for method in ctx.parameters["methods"]:
        frame = rows[rows["method"] == method]
        figure = error_figure(
            {method: frame},
            f"{method}: body-axis error, first trial",
            time=TIME,
            spans=spans,
            xlabel=xlabel,
        )
        names.append(save_figure(figure, ctx.out_dir, f"error_{method}.png"))
    drawn = {f: rows[rows["method"] == f] for f in FIGURE_FILTERS if f in filters}
    if drawn:
        title = (
            f"{', '.join(drawn)}: body-axis error, first trial (y fitted to t >= {SETTLE_S:g} s)"
        )
        figure = error_figure(
            drawn, title, time=TIME, spans=spans, xlabel=xlabel, fit_from=SETTLE_S
        )
        names.append(save_figure(figure, ctx.out_dir, "filter_errors.png"))
        figure = error_figure(
            drawn,
            f"{', '.join(drawn)}: gyro-bias error, first trial (y fitted to t >= {SETTLE_S:g} s)",
            values=[f"bias_err_{a}_deg_h" for a in AXES],
            sigmas=[f"bias_sigma_{a}_deg_h" for a in AXES],
            unit="deg/h",
            names=[f"bias {a}" for a in AXES],
            time=TIME,
            spans=spans,
            xlabel=xlabel,
            fit_from=SETTLE_S,
        )
        names.append(save_figure(figure, ctx.out_dir, "gyro_bias.png"))
    return names


def report(ctx: ReportContext) -> str:
    """Markdown: Table 1 beside ours, the filters, integrity, figures (written to ``out_dir``)."""
    present = set(ctx.rows["method"])
    methods = [m for m in ctx.parameters["methods"] if m in present]
    filters = [f for f in ctx.parameters.get("filters", []) if f in present]
    stats = interval_statistics(ctx.rows, methods + filters)
    return document(
        [
            table1_section(ctx, stats),
            filter_section(ctx, stats, filters) if filters else "",
            integrity_section(ctx.rows, KEYS, ctx.command),
            section("Figures", image_links(figures(ctx, filters))),
        ]
    )
