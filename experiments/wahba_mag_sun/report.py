"""Report of ``wahba-mag-sun``: our RMS beside seed 002 Table 1, consistency, figures,
and the gyro-aided filters through the eclipse."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from attopt.experiments.experiment import ReportContext
from attopt.experiments.wahba_mag_sun.scenario import START_UTC, build_geometry
from attopt.formulations.gyro import GYRO_MODELS, GyroModel

# Seed 002 Table 1 (RMS error, deg; "nd" = no data): method -> interval -> (roll, pitch, yaw).
SEED002_TABLE1: dict[str, dict[str, tuple[float, float, float] | None]] = {
    "triad": {
        "before_eclipse": (5.53, 1.81, 5.42),
        "eclipse": None,
        "after_eclipse": (4.07, 1.70, 1.14),
    },
    "svd": {
        "before_eclipse": (3.38, 1.79, 0.96),
        "eclipse": (100.09, 28.33, 200.10),
        "after_eclipse": (2.69, 1.64, 1.07),
    },
    "q_method": {
        "before_eclipse": (3.38, 1.79, 0.97),
        "eclipse": (100.19, 30.09, 194.19),
        "after_eclipse": (2.69, 1.65, 1.07),
    },
    "quest": {
        "before_eclipse": (3.39, 1.87, 0.98),
        "eclipse": (93.19, 30.12, 194.21),
        "after_eclipse": (2.72, 1.65, 1.11),
    },
    "foam": {
        "before_eclipse": (4.26, 2.21, 1.00),
        "eclipse": None,
        "after_eclipse": (2.93, 0.84, 1.98),
    },
}
INTERVAL_ORDER = ("before_eclipse", "eclipse", "after_eclipse")
FILTER_LABELS = {
    "mekf": "MEKF",
    "usque": "USQUE",
    "rts": "RTS smoother over the MEKF",
    "fg_batch": "GTSAM batch smoother (fg_batch)",
}
FIGURE_FILTERS = ("mekf", "rts")
"""Filters drawn in ``filter_errors.png`` (USQUE's curve is indistinguishable from the MEKF's)."""


def _rms(series: pd.Series) -> float:
    values = series.dropna().to_numpy()
    return float(np.sqrt(np.mean(values**2))) if values.size else float("nan")


def consistency_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per method and interval: Euler-difference RMS, mean NEES, share inside 3 sigma, RMS/CRB."""
    valid = rows[rows["valid"]]
    groups = valid.groupby(["method", "interval"], sort=False)
    out = groups.agg(
        roll_rms_deg=("err_x_deg", _rms),
        pitch_rms_deg=("err_y_deg", _rms),
        yaw_rms_deg=("err_z_deg", _rms),
        euler_roll_rms_deg=("euler_roll_err_deg", _rms),
        euler_pitch_rms_deg=("euler_pitch_err_deg", _rms),
        euler_yaw_rms_deg=("euler_yaw_err_deg", _rms),
        mean_nees=("nees", "mean"),
    )
    inside = valid.assign(
        inside=(valid["err_x_deg"].abs() <= 3 * valid["sigma_x_deg"])
        & (valid["err_y_deg"].abs() <= 3 * valid["sigma_y_deg"])
        & (valid["err_z_deg"].abs() <= 3 * valid["sigma_z_deg"])
    )
    out["inside_3sigma"] = inside.groupby(["method", "interval"], sort=False)["inside"].mean()
    total = np.sqrt(valid["err_x_deg"] ** 2 + valid["err_y_deg"] ** 2 + valid["err_z_deg"] ** 2)
    bound = np.sqrt(
        valid["bound_x_deg"] ** 2 + valid["bound_y_deg"] ** 2 + valid["bound_z_deg"] ** 2
    )
    ratio = valid.assign(e2=total**2, b2=bound**2).groupby(["method", "interval"], sort=False)
    out["rms_over_crb"] = np.sqrt(ratio["e2"].mean() / ratio["b2"].mean())
    return out.reset_index()


def _fmt(x: float) -> str:
    return "-" if not np.isfinite(x) else f"{x:.3f}"


def _paper(method: str, interval: str) -> str:
    entry = SEED002_TABLE1.get(method, {}).get(interval, "n/a")
    if entry == "n/a":
        return "not in seed 002"
    if entry is None:
        return "nd"
    return " / ".join(f"{v:.2f}" for v in entry)


def _first_trial(rows: pd.DataFrame) -> pd.DataFrame:
    """Rows of the first setting's first trial (trial 0 of a complete sweep)."""
    rows = rows[rows["setting_index"] == rows["setting_index"].min()]
    return rows[rows["trial_index"] == rows["trial_index"].min()]


def _figures(ctx: ReportContext) -> list[str]:
    rows = _first_trial(ctx.rows)
    rows = rows[rows["method"].isin(ctx.parameters["methods"])]
    geometry = build_geometry(ctx.parameters["duration_s"], ctx.parameters["step_s"])
    names = []
    for method, frame in rows.groupby("method", sort=False):
        fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
        for ax, axis, label in zip(axes, "xyz", ("roll (x)", "pitch (y)", "yaw (z)"), strict=True):
            ax.plot(frame["t"], frame[f"err_{axis}_deg"], lw=0.5, label="error")
            three = 3 * frame[f"sigma_{axis}_deg"]
            ax.plot(frame["t"], three, "r", lw=0.8, label="+/- 3 sigma (own covariance)")
            ax.plot(frame["t"], -three, "r", lw=0.8)
            if geometry.eclipse_interval is not None:
                ax.axvspan(*geometry.eclipse_interval, color="0.85", label="eclipse (no solution)")
            ax.set_ylabel(f"{label} [deg]")
        axes[0].legend(loc="upper right", fontsize=7)
        axes[0].set_title(f"{method}: body-axis attitude error, trial 0")
        axes[-1].set_xlabel(f"t [s] from {START_UTC} UTC")
        fig.tight_layout()
        name = f"error_{method}.png"
        fig.savefig(ctx.out_dir / name, dpi=110)
        plt.close(fig)
        names.append(name)
    return names


def report(ctx: ReportContext) -> str:
    """Markdown: comparison with seed 002 Table 1, consistency, discussion, figures."""
    geometry = build_geometry(ctx.parameters["duration_s"], ctx.parameters["step_s"])
    summary = ctx.summary.set_index(["method", "interval"])
    consistency = consistency_table(ctx.rows).set_index(["method", "interval"])
    lines = ["## Seed 002 Table 1 beside ours", ""]
    if geometry.eclipse_interval is None:
        lines.append("The window holds no eclipse.")
    else:
        start, end = geometry.eclipse_interval
        lines.append(
            f"Eclipse (cylindrical shadow) from t = {start:.0f} s to {end:.0f} s "
            f"({end - start:.0f} s); seed 002 had 1000-1500 s. Intervals: before_eclipse "
            f"[0, {start:.0f}), eclipse [{start:.0f}, {end:.0f}), after_eclipse [{end:.0f}, "
            f"{ctx.parameters['duration_s']:.0f})."
        )
    lines += [
        "",
        "Ours: RMS of the body-axis error components (roll x / pitch y / yaw z, deg), and the",
        "RMS of 3-2-1 Euler-angle differences (the quantity seed 002 tabulates). RMS / CRB is the",
        "total RMS error over the RMS of the Cramer-Rao bound; NEES uses the method's own",
        "covariance (3 when consistent); 'inside 3 sigma' is the share of epochs whose error is",
        "within 3 sigma on all three axes.",
        "",
        "| method | interval | ours roll / pitch / yaw | ours Euler-difference | seed 002 "
        "| valid | RMS / CRB | mean NEES (3) | inside 3 sigma |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method in ctx.parameters["methods"]:
        for interval in INTERVAL_ORDER:
            if (method, interval) not in summary.index:
                continue
            s = summary.loc[(method, interval)]
            c = (
                consistency.loc[(method, interval)]
                if (method, interval) in consistency.index
                else None
            )
            ours = " / ".join(_fmt(s[f"{a}_rms_deg"]) for a in ("roll", "pitch", "yaw"))
            if c is None:
                euler = extra = "-"
                cols = ["-", "-", "-"]
            else:
                euler = " / ".join(_fmt(c[f"euler_{a}_rms_deg"]) for a in ("roll", "pitch", "yaw"))
                cols = [_fmt(c["rms_over_crb"]), _fmt(c["mean_nees"]), f"{c['inside_3sigma']:.3f}"]
                extra = euler
            lines.append(
                f"| {method} | {interval} | {ours} | {extra} | {_paper(method, interval)} | "
                f"{s['valid_fraction']:.3f} | {' | '.join(cols)} |"
            )
    lines += ["", *_discussion(ctx, summary, consistency), ""]
    lines += _filter_section(ctx, consistency)
    lines += ["## Figures", ""] + [f"![{n}]({n})" for n in _figures(ctx)]
    return "\n".join(lines) + "\n"


def _paper_ratio(table: pd.DataFrame, prefix: str) -> tuple[float, float]:
    """Range of seed 002 RMS / our RMS over the rows of ``table`` the seed reports."""
    ratios = []
    for row in table.itertuples():
        paper = SEED002_TABLE1.get(row.method, {}).get(row.interval)
        if paper is None:
            continue
        for axis, value in zip(("roll", "pitch", "yaw"), paper, strict=True):
            ratios.append(value / getattr(row, f"{prefix}{axis}_rms_deg"))
    return (min(ratios), max(ratios)) if ratios else (float("nan"), float("nan"))


def _discussion(ctx: ReportContext, summary: pd.DataFrame, consistency: pd.DataFrame) -> list[str]:
    optimal = [m for m in ctx.parameters["methods"] if m != "triad"]
    sunlit = consistency.reset_index()
    sunlit = sunlit[sunlit["interval"] != "eclipse"]
    opt = sunlit[sunlit["method"].isin(optimal)]
    eclipse = summary.reset_index()
    eclipse = eclipse[
        (eclipse["interval"] == "eclipse") & eclipse["method"].isin(ctx.parameters["methods"])
    ]
    reasons = ctx.rows.loc[~ctx.rows["valid"], "reason"].value_counts()
    lines = ["### Discussion", ""]
    if not opt.empty:
        lo, hi = _paper_ratio(opt, "")
        elo, ehi = _paper_ratio(opt, "euler_")
        lines.append(
            f"- **Sunlit accuracy.** The optimal solvers reach RMS / CRB between "
            f"{opt['rms_over_crb'].min():.3f} and {opt['rms_over_crb'].max():.3f}: they are "
            "efficient, and agree with each other to solver precision. Their mean NEES is "
            f"{opt['mean_nees'].min():.2f}-{opt['mean_nees'].max():.2f} (3 for a consistent "
            f"covariance). Seed 002's sunlit RMS values are {lo:.1f} to {hi:.1f} times our "
            "body-axis RMS. Measured as the seed measures (3-2-1 Euler-angle differences) the "
            f"ratio shrinks to {elo:.1f}-{ehi:.1f}: much of the seed's large roll and yaw RMS is "
            "the Euler-angle artefact described below. Where the seed still exceeds us, it "
            "exceeds what its stated noise (0.002 and 0.008 direction cosines, 0.11 and 0.46 "
            "deg) allows any optimal estimator, so its simulation had error sources it does not "
            "describe (its Table 1 also differs between SVD and q-method, which solve the same "
            "problem exactly)."
        )
    triad = sunlit[sunlit["method"] == "triad"]
    if not triad.empty and not opt.empty:
        lines.append(
            f"- **TRIAD** reaches RMS / CRB {triad['rms_over_crb'].min():.3f}-"
            f"{triad['rms_over_crb'].max():.3f}: it discards part of the magnetometer's "
            "information but anchors on the accurate Sun sensor. Seed 002's eq. 11 labels the "
            "anchor variance as the magnetometer's; the Monte Carlo test "
            "(tests/test_wahba_covariance.py) shows the anchor's variance is the right one."
        )
    if not eclipse.empty:
        lines.append(
            f"- **Eclipse.** With no Sun measurement only the magnetometer remains: every "
            f"method reports the epochs as unobservable (valid fraction "
            f"{eclipse['valid_fraction'].max():.3f}) instead of the seed's 93-200 deg errors. "
            "A single vector cannot fix the rotation about itself; the gyro-aided filters "
            "(next section) carry the attitude through."
        )
    euler = sunlit.assign(gap=sunlit["euler_roll_rms_deg"] / sunlit["roll_rms_deg"])
    if not euler.empty and np.isfinite(euler["gap"]).any():
        lines.append(
            f"- **Euler differences.** Near the +/-87 deg pitch peaks the 3-2-1 roll and yaw "
            f"angles are ill-defined (gimbal lock), so Euler-angle differences inflate: the "
            f"Euler-difference roll RMS is up to {np.nanmax(euler['gap']):.1f} times the "
            "body-axis roll RMS. Seed 002 notes oscillations near 90 deg pitch for the same "
            "reason; we report body-axis errors, which have no such singularity."
        )
    if len(reasons):
        top = "; ".join(f"{r} ({n} rows)" for r, n in reasons.head(3).items())
        lines.append(f"- **Invalid epochs** by reason: {top}.")
    return lines


# ------------------------------------------------------------------ filters ---

SETTLE_S = 120.0
"""Figures scale their y axes to the errors after this time (the filters converge
from the initial attitude error within it)."""


def _filters(ctx: ReportContext) -> list[str]:
    present = set(ctx.rows["method"])
    return [f for f in ctx.parameters.get("filters", []) if f in present]


def _gyro_sentence(model: GyroModel, initial_sigma_deg: float) -> str:
    arw = np.degrees(model.sigma_v) * 60.0  # deg/s^(1/2) -> deg/h^(1/2)
    rrw = np.degrees(model.sigma_u) * 3600.0 * 60.0  # deg/s^(3/2) -> deg/h^(3/2)
    return (
        f"Seed 002 has no gyro: the filters integrate a simulated `{model.name}` gyro "
        f"(`formulations/gyro.py`) sampled at {model.rate_hz:g} Hz, angle random walk "
        f"{arw:.3g} deg/h^(1/2), rate random walk {rrw:.3g} deg/h^(3/2) (deg/h per h^(1/2)), "
        f"turn-on bias drawn per trial from N(0, ({np.degrees(model.initial_bias_sigma) * 3600:.0f}"
        f" deg/h)^2) per axis. They start from an attitude error drawn from N(0, "
        f"({initial_sigma_deg:g} deg)^2) per axis and a zero bias estimate, with exactly that "
        "prior covariance, and use the single-frame methods' Sun and magnetometer vectors "
        "(one two-vector measurement per epoch, the field alone in eclipse). The gyro and the "
        "prior draw from their own random stream, so the single-frame rows are unchanged."
    )


def filter_table(rows: pd.DataFrame, filters: list[str]) -> pd.DataFrame:
    """Per filter and interval: valid share, mean 6-state NEES, largest 3 sigma per axis,
    RMS bias error per axis (deg/h)."""
    frame = rows[rows["method"].isin(filters)]
    keys = ["method", "interval"]
    out = frame.groupby(keys, sort=False).agg(valid_fraction=("valid", "mean"))
    valid = frame[frame["valid"]]
    groups = valid.groupby(keys, sort=False)
    out["mean_nees_full"] = groups["nees_full"].mean()
    for axis in "xyz":
        out[f"max_3sigma_{axis}_deg"] = 3.0 * groups[f"sigma_{axis}_deg"].max()
        out[f"bias_err_{axis}_rms_deg_h"] = groups[f"bias_err_{axis}_deg_h"].agg(_rms)
    return out.reset_index()


def runtime_table(rows: pd.DataFrame, filters: list[str]) -> pd.Series:
    """Mean wall time of one pass (s) per filter (``rts``: MEKF plus backward pass)."""
    frame = rows[rows["method"].isin(filters)]
    per_trial = frame.groupby(["setting_index", "trial_index", "method"])["runtime_s"].first()
    return per_trial.groupby("method").mean()


def _filter_section(ctx: ReportContext, consistency: pd.DataFrame) -> list[str]:
    filters = _filters(ctx)
    if not filters:
        return []
    model = GYRO_MODELS[ctx.parameters.get("gyro", "mems")]
    duration = ctx.parameters["duration_s"]
    table = filter_table(ctx.rows, filters).set_index(["method", "interval"])
    runtime = runtime_table(ctx.rows, filters)
    lines = [
        "## Gyro-aided filters through the eclipse",
        "",
        _gyro_sentence(model, ctx.parameters.get("initial_sigma_deg", 10.0)),
        "",
        "RMS of the body-axis errors (deg) over the valid epochs of all trials; RMS / CRB is "
        "against the single-frame Cramer-Rao bound of the same epoch (undefined in eclipse), "
        "which a filter may beat because it also uses the gyro and the other epochs; NEES (3) "
        "uses the attitude block of the filter's covariance, NEES (6) the full attitude + bias "
        "covariance (3 and 6 when consistent); the before-eclipse values include the "
        "convergence from the initial error.",
        "",
        "| filter | interval | valid | RMS roll / pitch / yaw | RMS / CRB | mean NEES (3) "
        "| mean NEES (6) | inside 3 sigma |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for method in filters:
        for interval in INTERVAL_ORDER:
            if (method, interval) not in table.index:
                continue
            f = table.loc[(method, interval)]
            c = (
                consistency.loc[(method, interval)]
                if (method, interval) in consistency.index
                else None
            )
            if c is None:
                cells = ["-"] * 5
            else:
                cells = [
                    " / ".join(_fmt(c[f"{a}_rms_deg"]) for a in ("roll", "pitch", "yaw")),
                    _fmt(c["rms_over_crb"]),
                    _fmt(c["mean_nees"]),
                    _fmt(f["mean_nees_full"]),
                    f"{c['inside_3sigma']:.3f}",
                ]
            lines.append(
                f"| {method} | {interval} | {f['valid_fraction']:.3f} | {' | '.join(cells)} |"
            )
    lines += [
        "",
        f"Largest 3 sigma (the filter's own attitude covariance) during the eclipse, RMS "
        f"gyro-bias error after it, and the mean wall time of one {duration:.0f} s pass "
        f"({duration * model.rate_hz:.0f} gyro samples, {duration / ctx.parameters['step_s']:.0f}"
        " epochs; wall time in the sweep's worker process, including the measurement models' "
        "evaluation, so concurrent workers slow it down), also scaled to an hour of data:",
        "",
        "| filter | max 3 sigma in eclipse roll / pitch / yaw (deg) | bias error RMS after "
        "eclipse x / y / z (deg/h) | runtime per pass (s) | per hour of data (s) |",
        "|---|---|---|---|---|",
    ]
    for method in filters:
        eclipse = table.loc[(method, "eclipse")] if (method, "eclipse") in table.index else None
        after = (
            table.loc[(method, "after_eclipse")]
            if (method, "after_eclipse") in table.index
            else None
        )
        sigma = (
            "-"
            if eclipse is None
            else " / ".join(_fmt(eclipse[f"max_3sigma_{a}_deg"]) for a in "xyz")
        )
        bias = (
            "-"
            if after is None
            else " / ".join(_fmt(after[f"bias_err_{a}_rms_deg_h"]) for a in "xyz")
        )
        seconds = runtime.get(method, float("nan"))
        lines.append(
            f"| {FILTER_LABELS.get(method, method)} | {sigma} | {bias} | {seconds:.2f} | "
            f"{seconds * 3600.0 / duration:.2f} |"
        )
    lines += ["", *_bound_lines(ctx, filters)]
    lines += ["", *_filter_discussion(ctx, filters, consistency, runtime), ""]
    lines += [f"![{n}]({n})" for n in _filter_figures(ctx, filters)]
    return [*lines, ""]


def _bound_lines(ctx: ReportContext, filters: list[str]) -> list[str]:
    """RMS of each gyro-aided method against the posterior bound of the pass (issue 6)."""
    rows = ctx.rows[ctx.rows["method"].isin(filters) & ctx.rows["valid"].astype(bool)]
    if "pbound_x_deg" not in rows or rows["pbound_x_deg"].isna().all():
        return []
    lines = [
        "RMS (deg) against the posterior Cramer-Rao bound of the whole pass (`bound`: RMS of "
        "the smoother's marginal sigma at the truth, gyro and every vector; "
        "`attopt.experiments.filtering.posterior_bound`), per interval:",
        "",
        "| filter | " + " | ".join(f"{i}: RMS / bound" for i in INTERVAL_ORDER) + " |",
        "|---|" + "---|" * len(INTERVAL_ORDER),
    ]
    for method in filters:
        cells = []
        for interval in INTERVAL_ORDER:
            chosen = rows[(rows["method"] == method) & (rows["interval"] == interval)]
            if not len(chosen):
                cells.append("-")
                continue
            rms, bound = (
                float(np.sqrt(sum((chosen[c.format(a)] ** 2).mean() for a in "xyz")))
                for c in ("err_{}_deg", "pbound_{}_deg")
            )
            cells.append(f"{rms:.3f} / {bound:.3f} = {rms / bound:.2f}")
        lines.append(f"| {FILTER_LABELS.get(method, method)} | " + " | ".join(cells) + " |")
    return lines


def _total_rms(c: pd.Series) -> float:
    return float(np.sqrt(sum(c[f"{a}_rms_deg"] ** 2 for a in ("roll", "pitch", "yaw"))))


def _filter_discussion(
    ctx: ReportContext, filters: list[str], consistency: pd.DataFrame, runtime: pd.Series
) -> list[str]:
    lines = ["### Discussion (filters)", ""]
    single = [m for m in ctx.parameters["methods"] if m != "triad"] or list(
        ctx.parameters["methods"]
    )
    for interval in ("before_eclipse", "after_eclipse"):
        best = [
            (_total_rms(consistency.loc[(m, interval)]), m)
            for m in single
            if (m, interval) in consistency.index
        ]
        ours = [
            (_total_rms(consistency.loc[(f, interval)]), f)
            for f in filters
            if (f, interval) in consistency.index
        ]
        if best and ours:
            b, bm = min(best)
            text = ", ".join(f"{f} {v:.3f}" for v, f in ours)
            lines.append(
                f"- **{interval.replace('_', ' ').capitalize()}**: total RMS {text} deg against "
                f"{b:.3f} deg for the best single-frame method ({bm}): the gyro averages the "
                "vector noise over many epochs."
            )
    in_eclipse = [f for f in filters if (f, "eclipse") in consistency.index]
    if in_eclipse:
        text = ", ".join(
            f"{f} {_total_rms(consistency.loc[(f, 'eclipse')]):.3f} deg (NEES "
            f"{consistency.loc[(f, 'eclipse'), 'mean_nees']:.2f})"
            for f in in_eclipse
        )
        lines.append(
            f"- **Eclipse**: every single-frame method is invalid; the filters stay valid with "
            f"total RMS {text}. The rotation about the field direction is carried by the gyro "
            "alone, so its uncertainty grows through the eclipse and collapses when the Sun "
            "returns; the RTS smoother also uses the measurements after the eclipse."
        )
    if "rts" in runtime and "mekf" in runtime:
        lines.append(
            f"- **Runtime**: the RTS row's time is the MEKF's plus the backward pass, "
            f"{runtime['rts'] - runtime['mekf']:.2f} s per pass; the MEKF is run once per trial "
            "and smoothed."
        )
    return lines


def _shade_eclipse(ax: plt.Axes, geometry, label: str | None = None) -> None:
    if geometry.eclipse_interval is not None:
        ax.axvspan(*geometry.eclipse_interval, color="0.88", label=label)


def _settled_limit(t: np.ndarray, *series: np.ndarray) -> float:
    later = t >= t.min() + SETTLE_S
    values = np.concatenate([np.abs(np.asarray(s, dtype=float)[later]) for s in series])
    values = values[np.isfinite(values)]
    return 1.15 * float(values.max()) if values.size else 1.0


def _filter_figures(ctx: ReportContext, filters: list[str]) -> list[str]:
    rows = _first_trial(ctx.rows)
    geometry = build_geometry(ctx.parameters["duration_s"], ctx.parameters["step_s"])
    names = []
    drawn = [f for f in FIGURE_FILTERS if f in filters]
    if drawn:
        fig, axes = plt.subplots(
            3,
            len(drawn),
            figsize=(5.5 * len(drawn) + 1, 7.5),
            sharex=True,
            sharey="row",
            squeeze=False,
        )
        for column, method in enumerate(drawn):
            frame = rows[rows["method"] == method]
            t = frame["t"].to_numpy()
            for row, (axis, label) in enumerate(
                zip("xyz", ("roll (x)", "pitch (y)", "yaw (z)"), strict=True)
            ):
                ax = axes[row, column]
                error = frame[f"err_{axis}_deg"].to_numpy()
                three = 3.0 * frame[f"sigma_{axis}_deg"].to_numpy()
                _shade_eclipse(ax, geometry, "eclipse (Sun sensor blind)")
                ax.plot(t, error, lw=0.5, label="error")
                ax.plot(t, three, "r", lw=0.8, label="+/- 3 sigma (own covariance)")
                ax.plot(t, -three, "r", lw=0.8)
                limit = _settled_limit(
                    t,
                    *(
                        rows.loc[rows["method"] == m, f"{c}_{axis}_deg"].to_numpy()
                        * (3.0 if c == "sigma" else 1.0)
                        for m in drawn
                        for c in ("err", "sigma")
                    ),
                )
                ax.set_ylim(-limit, limit)
                if column == 0:
                    ax.set_ylabel(f"{label} [deg]")
            axes[0, column].set_title(f"{FILTER_LABELS[method]}, trial 0")
            axes[-1, column].set_xlabel(f"t [s] from {START_UTC} UTC")
        axes[0, 0].legend(loc="upper right", fontsize=7)
        fig.suptitle(
            f"Body-axis attitude error (y axes scaled to t > {SETTLE_S:.0f} s; the "
            "convergence from the initial error is off scale)",
            fontsize=9,
        )
        fig.tight_layout()
        names.append(_save(fig, ctx, "filter_errors.png"))
    names.append(_bias_figure(ctx, rows, filters, geometry))
    return names


def _bias_figure(ctx: ReportContext, rows: pd.DataFrame, filters: list[str], geometry) -> str:
    fig, axes = plt.subplots(3, 2, figsize=(12, 7.5), sharex=True)
    first = rows[rows["method"] == filters[0]]
    t = first["t"].to_numpy()
    colours = {f: f"C{i}" for i, f in enumerate(filters)}
    # USQUE's estimates coincide with the MEKF's: the first filters are drawn wider.
    widths = {f: 0.6 + 0.6 * (len(filters) - 1 - i) for i, f in enumerate(filters)}
    for row, axis in enumerate("xyz"):
        truth = (first[f"bias_{axis}_deg_h"] - first[f"bias_err_{axis}_deg_h"]).to_numpy()
        left, right = axes[row]
        for ax in (left, right):
            _shade_eclipse(ax, geometry, "eclipse" if row == 0 else None)
        left.plot(t, truth, "k", lw=1.2, label="true")
        estimates, errors, sigmas = [truth], [], []
        for method in filters:
            frame = rows[rows["method"] == method]
            estimate = frame[f"bias_{axis}_deg_h"].to_numpy()
            error = frame[f"bias_err_{axis}_deg_h"].to_numpy()
            three = 3.0 * frame[f"bias_sigma_{axis}_deg_h"].to_numpy()
            left.plot(frame["t"], estimate, colours[method], lw=widths[method], label=method)
            right.plot(
                frame["t"], error, colours[method], lw=widths[method], label=f"{method} error"
            )
            right.plot(frame["t"], three, colours[method], lw=0.8, ls="--")
            right.plot(frame["t"], -three, colours[method], lw=0.8, ls="--")
            estimates.append(estimate)
            errors.append(error)
            sigmas.append(three)
        later = t >= t.min() + SETTLE_S
        stacked = np.concatenate([e[later] for e in estimates])
        stacked = stacked[np.isfinite(stacked)]
        if stacked.size:
            span = max(np.ptp(stacked), 1.0)
            left.set_ylim(stacked.min() - 0.2 * span, stacked.max() + 0.2 * span)
        limit = _settled_limit(t, *errors, *sigmas)
        right.set_ylim(-limit, limit)
        left.set_ylabel(f"bias {axis} [deg/h]")
        right.set_ylabel(f"error {axis} [deg/h]")
    axes[0, 0].set_title("gyro bias: estimated and true, trial 0")
    axes[0, 1].set_title("bias error and +/- 3 sigma (dashed), trial 0")
    axes[0, 0].legend(loc="upper right", fontsize=7)
    axes[0, 1].legend(loc="upper right", fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel(f"t [s] from {START_UTC} UTC")
    fig.suptitle(f"y axes scaled to t > {SETTLE_S:.0f} s (the estimates start from 0)", fontsize=9)
    fig.tight_layout()
    return _save(fig, ctx, "gyro_bias.png")


def _save(fig: plt.Figure, ctx: ReportContext, name: str) -> str:
    fig.savefig(ctx.out_dir / name, dpi=110)
    plt.close(fig)
    return name
