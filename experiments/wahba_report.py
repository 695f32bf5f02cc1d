"""Report of ``wahba-mag-sun``: our RMS beside seed 002 Table 1, consistency, figures."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from experiments.experiment import ReportContext
from experiments.scenarios.wahba_mag_sun import START_UTC, build_geometry

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


def _figures(ctx: ReportContext) -> list[str]:
    rows = ctx.rows[ctx.rows["trial_index"] == ctx.rows["trial_index"].min()]
    rows = rows[rows["setting_index"] == rows["setting_index"].min()]
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
    eclipse = eclipse[eclipse["interval"] == "eclipse"]
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
            "A single vector cannot fix the rotation about itself; the filters of a later issue "
            "carry the attitude through."
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
