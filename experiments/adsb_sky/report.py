"""Report of ``adsb-sky``: every estimator per sky, and Liu et al. 2023's claims decided.

Tables from the stored rows (``adsb-snr``'s columns and ``sky``):

* per sky and estimator, the received observations per epoch, the valid fraction, the
  RMS error over the valid epochs and its ratio to the bound (single-frame rows: the
  Cramer-Rao bound of the received SNRs, ``bound_*``; gyro-aided rows: the posterior
  bound of the pass, ``pbound_*``, where the rows have it), and the integrity share;
  gyro-aided rows from :func:`~attopt.experiments.adsb_snr.report.settled_from` on;
* the paper's four claims, each with the rule that decides it and its number per sky
  (:data:`CLAIM_RULES`);
* the integrity section of every report;
* a figure of the observations per epoch and the RMS of every estimator, per sky
  (:func:`sky_figure`).

Both bounds assume the powers the receiver is told (the nominal ones): under a sky
with unknown transmitter powers they are optimistic, and an RMS far above them
measures what the unmodelled powers cost.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import matplotlib.pyplot as plt
import matplotlib.ticker as ticker
import numpy as np
import pandas as pd

from attopt.experiments.adsb_snr.report import NO_GYRO, settled_from
from attopt.experiments.environment.adsb_collisions import SQUITTER_RATE_HZ
from attopt.experiments.environment.adsb_receiver import ReceiverChain, error_table, table_at
from attopt.experiments.experiment import ReportContext
from attopt.experiments.reporting.figures import image_links, save_figure
from attopt.experiments.reporting.integrity import integrity_section
from attopt.experiments.reporting.statistics import (
    AXES,
    INTEGRITY_PROBABILITY,
    integrity,
    nees_threshold,
    rms,
    total_rms,
    valid_mask,
)
from attopt.experiments.reporting.tables import document, made_by, markdown_table, section

KEYS = ["sky", "gyro", "method"]
"""The groups of every table: sky, then gyro (``none`` for single frame), then method."""
INTEGRITY_TARGET = 1e-3
"""Largest integrity share for an estimator to count as honest in the claims."""
MIN_VALID = 0.5
"""Least valid fraction for a single-frame method to count in the claims."""
MIN_VALID_GYRO = 0.9
"""Least valid fraction (settled epochs) for a gyro-aided estimator to count."""
DEGREE_LEVEL_DEG = 2.13
"""Liu et al. 2023 Table 2's largest single-frame RMS (QUEST's roll): degree level."""
GYRO_RMS_DEG = 0.28
"""Liu et al. 2023 Table 2's largest MEKF RMS (yaw): the 0.15-0.28 deg claim."""
CONVERGED_OBSERVATIONS = 100
"""Liu et al. 2023 sec. 5.2, Fig. 10: no further gain beyond about 100 observations."""
NO_GAIN_RATIO = 0.9
"""RMS at >= 200 observations over RMS at 100-199 above which there is no further gain."""
MIN_BIN_EPOCHS = 30
"""Fewest valid epochs per bin for the observation claim to be decided."""
THRESHOLD_DB = 6.0
"""Liu et al. 2023 sec. 5.1: the SNR above which a message is usable."""
THRESHOLD_TOLERANCE_DB = 1.0
"""How far the chain's 50 % point may lie from 6 dB for the threshold claim to hold."""
CLAIM_RULES = {
    "degree-level single frame": (
        f"the best single-frame method with valid fraction >= {MIN_VALID} and integrity share "
        f"<= {INTEGRITY_TARGET:g} has every axis RMS <= {DEGREE_LEVEL_DEG} deg (Table 2's "
        "largest single-frame RMS)"
    ),
    "0.15-0.28 deg with the gyro": (
        f"the best gyro-aided estimator with valid fraction >= {MIN_VALID_GYRO} (settled epochs)"
        f" and integrity share <= {INTEGRITY_TARGET:g} has every axis RMS <= {GYRO_RMS_DEG} deg"
    ),
    "no gain beyond 100 observations": (
        "the NLP's RMS over valid epochs with >= 200 observations is at least "
        f"{NO_GAIN_RATIO} x its RMS at 100-199 (each bin >= {MIN_BIN_EPOCHS} epochs)"
    ),
    "6 dB usable threshold": (
        "the link SNR at which the receiver chain hears an aircraft in half the epochs "
        f"({SQUITTER_RATE_HZ} messages/s, no collisions) lies within "
        f"{THRESHOLD_TOLERANCE_DB} dB of 6 dB"
    ),
}
"""How each claim is decided (the report prints these rules)."""


def _gyro_aided(rows: pd.DataFrame) -> np.ndarray:
    return (rows["gyro"] != NO_GYRO).to_numpy()


def assessed_rows(ctx: ReportContext) -> pd.DataFrame:
    """The rows the accuracy columns use: every single-frame row, and the gyro-aided rows
    from :func:`~attopt.experiments.adsb_snr.report.settled_from` on."""
    rows = ctx.rows
    settled = (rows["t_s"] >= settled_from(ctx)).to_numpy()
    return rows[~_gyro_aided(rows) | settled]


def _bound_ratio(valid: pd.DataFrame, bound: str) -> float:
    """Total RMS over the RMS of ``bound`` on the valid rows with a finite bound."""
    columns = [f"{bound}_{axis}_deg" for axis in AXES]
    if columns[0] not in valid:
        return float("nan")
    bounded = valid[np.isfinite(valid[columns].to_numpy(dtype=float)).all(axis=1)]
    return total_rms(bounded) / total_rms(bounded, bound) if len(bounded) else float("nan")


def sky_table(ctx: ReportContext) -> pd.DataFrame:
    """Per sky, gyro and method (module docstring): observations per epoch, valid
    fraction, RMS per axis and in all, RMS over the bound, integrity share, mean NEES."""
    rows = assessed_rows(ctx)
    shares = integrity(ctx.rows, KEYS)
    lines = []
    for (sky, gyro, method), group in rows.groupby(KEYS, sort=False):
        valid = group[valid_mask(group)]
        bound = "bound" if gyro == NO_GYRO else "pbound"
        share = shares.loc[(sky, gyro, method)]
        lines.append(
            {
                "sky": sky,
                "gyro": gyro,
                "method": method,
                "observations per epoch": float(group["n_obs"].mean()),
                "valid": float(valid_mask(group).mean()),
                **{f"RMS {axis} (deg)": rms(valid[f"err_{axis}_deg"]) for axis in AXES},
                "RMS (deg)": total_rms(valid),
                "RMS / bound": _bound_ratio(valid, bound),
                "integrity share": float(share["share_beyond"]),
                "mean NEES": float(share["mean_nees"]),
            }
        )
    return pd.DataFrame(lines)


def _sky_order(ctx: ReportContext) -> list[str]:
    return list(dict.fromkeys(ctx.rows["sky"]))


def _best(table: pd.DataFrame, honest: pd.Series) -> pd.Series | None:
    """The row of ``table`` with the lowest largest-axis RMS among the ``honest`` ones."""
    candidates = table[honest]
    if not len(candidates):
        return None
    worst_axis = candidates[[f"RMS {axis} (deg)" for axis in AXES]].max(axis=1)
    return candidates.loc[worst_axis.idxmin()]


def _label(line: pd.Series) -> str:
    """An estimator's name in the claims: its method, with its gyro if it has one."""
    return line["method"] if line["gyro"] == NO_GYRO else f"{line['method']} ({line['gyro']})"


def _accuracy_claim(
    table: pd.DataFrame, gyro_aided: bool, least_valid: float, limit_deg: float
) -> Callable[[str], tuple[str, str]]:
    """The verdict and deciding number of an accuracy claim for one sky."""

    def decide(sky: str) -> tuple[str, str]:
        mine = table[(table["sky"] == sky) & ((table["gyro"] != NO_GYRO) == gyro_aided)]
        if mine.empty:
            kind = "gyro-aided" if gyro_aided else "single-frame"
            return "not decided", f"no {kind} estimator in the run"
        honest = (mine["valid"] >= least_valid) & (mine["integrity share"] <= INTEGRITY_TARGET)
        best = _best(mine, honest)
        if best is None:
            most = mine.loc[mine["valid"].idxmax()]
            return "does not hold", (
                f"no estimator is valid at >= {least_valid:g} of its epochs with an integrity "
                f"share <= {INTEGRITY_TARGET:g}; the most valid: {_label(most)}, valid "
                f"{most['valid']:.3f}, integrity share {most['integrity share']:.3g}"
            )
        worst = max(best[f"RMS {axis} (deg)"] for axis in AXES)
        verdict = "holds" if worst <= limit_deg else "does not hold"
        return verdict, (
            f"{_label(best)}: largest axis RMS {worst:.3f} deg, valid {best['valid']:.3f}, "
            f"integrity share {best['integrity share']:.3g}"
        )

    return decide


def _observations_claim(ctx: ReportContext) -> Callable[[str], tuple[str, str]]:
    rows = ctx.rows

    def decide(sky: str) -> tuple[str, str]:
        nlp = rows[(rows["sky"] == sky) & (rows["method"] == "nlp")]
        if not len(nlp):
            return "not decided", "no `nlp` rows"
        valid = nlp[valid_mask(nlp)]
        low = valid[(valid["n_obs"] >= CONVERGED_OBSERVATIONS) & (valid["n_obs"] < 200)]
        high = valid[valid["n_obs"] >= 200]
        counts = f"{len(low)} and {len(high)} valid epochs"
        if min(len(low), len(high)) < MIN_BIN_EPOCHS:
            return "not decided", f"too few epochs: {counts}"
        ratio = total_rms(high) / total_rms(low)
        verdict = "holds" if ratio >= NO_GAIN_RATIO else "does not hold"
        return verdict, (
            f"RMS {total_rms(low):.3f} deg at 100-199, {total_rms(high):.3f} deg at >= 200 "
            f"(ratio {ratio:.2f}; {counts})"
        )

    return decide


def heard_half_the_time_db(chain: ReceiverChain, bandwidth_hz: float) -> float:
    """The link SNR (dB, noise in ``bandwidth_hz``) at which an aircraft sending
    :data:`SQUITTER_RATE_HZ` messages a second is heard in half the 1 s epochs by
    ``chain``: ``1 - exp(-6.2 p) = 1/2`` with ``p`` the table's decoding probability
    (:mod:`attopt.experiments.adsb_snr.sky`)."""
    frame = error_table(chain).frame
    to_sample = 10.0 * math.log10(bandwidth_hz / chain.sample_rate_hz)
    link = np.arange(-5.0, 25.0, 0.01)
    p, _, _ = table_at(frame, link + to_sample)
    heard = 1.0 - np.exp(-SQUITTER_RATE_HZ * p)
    return float(np.interp(0.5, heard, link))


def _threshold_claim(ctx: ReportContext) -> Callable[[str], tuple[str, str]]:
    receiver = ctx.parameters["receiver"]
    chain = ReceiverChain.model_validate(receiver.get("chain") or {})
    half = heard_half_the_time_db(chain, receiver["bandwidth_hz"])

    def decide(sky: str) -> tuple[str, str]:
        if sky not in ("chain", "real", "modelled"):
            return "assumed", "the paper's hard 6 dB threshold is the model of this sky"
        verdict = "holds" if abs(half - THRESHOLD_DB) <= THRESHOLD_TOLERANCE_DB else "does not hold"
        return verdict, f"heard in half the epochs at {half:.2f} dB (link SNR)"

    return decide


def claims_table(ctx: ReportContext, table: pd.DataFrame) -> pd.DataFrame:
    """One line per claim and sky: the verdict and the number that decides it."""
    deciders = {
        "degree-level single frame": _accuracy_claim(table, False, MIN_VALID, DEGREE_LEVEL_DEG),
        "0.15-0.28 deg with the gyro": _accuracy_claim(table, True, MIN_VALID_GYRO, GYRO_RMS_DEG),
        "no gain beyond 100 observations": _observations_claim(ctx),
        "6 dB usable threshold": _threshold_claim(ctx),
    }
    lines = []
    for claim, decide in deciders.items():
        for sky in _sky_order(ctx):
            verdict, number = decide(sky)
            lines.append(
                {"claim": claim, "sky": sky, "verdict": verdict, "deciding number": number}
            )
    return pd.DataFrame(lines)


def sky_figure(ctx: ReportContext, table: pd.DataFrame) -> str:
    """Bars per sky: the received observations per epoch, and the RMS error of each
    single-frame method and of each gyro-aided estimator with the last gyro of ``gyros``
    (valid epochs; a missing bar: no valid epoch).  Written to ``skies.png``; returns its
    name."""
    skies = _sky_order(ctx)
    single = table[table["gyro"] == NO_GYRO]
    gyros = [g for g in dict.fromkeys(table["gyro"]) if g != NO_GYRO]
    aided = table[table["gyro"] == gyros[-1]] if gyros else table.iloc[:0]
    panels = [("received observations per epoch", None), ("single frame: RMS (deg)", single)]
    if len(aided):
        panels.append((f"gyro-aided ({gyros[-1]} gyro): RMS (deg)", aided))
    figure, axes = plt.subplots(len(panels), 1, figsize=(10.0, 2.6 * len(panels)), squeeze=False)
    position = np.arange(len(skies))
    for ax, (title, rows) in zip(axes[:, 0], panels, strict=True):
        if rows is None:
            counts = table.drop_duplicates("sky").set_index("sky")["observations per epoch"]
            ax.bar(position, counts.reindex(skies).to_numpy(), color="grey")
        else:
            methods = list(dict.fromkeys(rows["method"]))
            width = 0.8 / max(len(methods), 1)
            for i, method in enumerate(methods):
                values = rows[rows["method"] == method].set_index("sky")["RMS (deg)"]
                offset = (i - 0.5 * (len(methods) - 1)) * width
                ax.bar(position + offset, values.reindex(skies).to_numpy(), width, label=method)
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
            ax.yaxis.set_minor_formatter(ticker.FormatStrFormatter("%g"))
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        ax.set_title(title, fontsize=9)
        ax.set_xticks(position, skies)
        ax.grid(True, axis="y", alpha=0.3)
    return save_figure(figure, ctx.out_dir, "skies.png")


def report(ctx: ReportContext) -> str:
    """Markdown: the estimators per sky, the claims, integrity."""
    if ctx.rows.empty:
        return document([integrity_section(ctx.rows, KEYS, ctx.command)])
    table = sky_table(ctx)
    start = settled_from(ctx)
    caption = (
        "Per sky and estimator: mean received observations per epoch; valid share of the "
        "epochs; RMS error per body axis and in all over the valid epochs; RMS over the RMS of "
        "the bound on the same epochs (single frame: the Cramer-Rao bound of the received "
        "SNRs; gyro-aided: the posterior bound of the pass, where the rows have it; both with "
        "the powers the receiver is told); integrity share: valid epochs whose NEES exceeds "
        f"the chi-square(3) {1 - INTEGRITY_PROBABILITY:g} quantile ({nees_threshold():.1f}). "
        f"Gyro-aided rows from t = {start:g} s (the filters' burn-in) except the integrity "
        "share, which uses every epoch." + made_by(ctx.command)
    )
    formats = {
        "observations per epoch": ".1f",
        "valid": ".3f",
        "RMS / bound": ".2f",
        "integrity share": ".3g",
        "mean NEES": ".3g",
    }
    rules = "\n".join(f"- **{claim}**: {rule}." for claim, rule in CLAIM_RULES.items())
    return document(
        [
            section("Estimators per sky", caption, markdown_table(table, formats, ".3f")),
            section(
                "Liu et al. 2023's claims under each sky",
                "Each claim is decided by a rule stated in advance:\n\n" + rules,
                markdown_table(claims_table(ctx, table)),
            ),
            integrity_section(ctx.rows, KEYS, ctx.command),
            section("Figures", image_links([sky_figure(ctx, table)])),
        ]
    )
