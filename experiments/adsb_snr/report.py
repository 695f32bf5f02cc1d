"""Report of ``adsb-snr``: Liu et al. 2023 Table 2 beside ours, runtimes, efficiency,
observations and accuracy by their number (Figs. 8-10), consistency, the gyro-aided
filters and smoothers, integrity and figures.

Tables only, from the stored rows (:mod:`attopt.experiments.adsb_snr.experiment`
documents their columns; filter rows carry ``gyro`` != ``"none"``).  What the
tables compare and why they differ from the paper: ``docs/results.md``,
``docs/filters.md``, ``docs/smoother.md``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import matplotlib.pyplot as plt
import matplotlib.ticker as ticker
import numpy as np
import pandas as pd

from attopt.experiments.adsb_snr.filters import gyro_label
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
    bounded_valid_rows,
    error_summary,
    finite_bound,
    inside_3_sigma,
    nees_interval,
    paired,
    rms,
    rms_ratio,
    rms_ratio_by_group,
    rms_ratio_standard_error,
    run_averaged_nees,
    signed_max,
    squared_norm,
    total_rms,
    valid_mask,
)
from attopt.experiments.reporting.tables import (
    document,
    joined,
    made_by,
    markdown_table,
    section,
)

PACKAGE = "attopt.experiments.adsb_snr"
EPOCH_KEYS = ("trial_index", "t_s")
"""A row's epoch: its trial and time."""
NO_GYRO = "none"
TABLE2_AXES = (("yaw", "z"), ("pitch", "y"), ("roll", "x"))
"""Table 2's column order: psi, theta, phi = yaw, pitch, roll."""
EULER = [f"euler_{name}_err_deg" for name, _ in TABLE2_AXES]
SIGMA = [f"sigma_{axis}_deg" for _, axis in TABLE2_AXES]
PAPER_ROWS = {"deterministic": "QUEST", "nlse": "NLSE"}
"""Our method -> its row in Table 2."""
SINGLE_EPOCH_METHODS = ("deterministic", "nlse", "nlp")
"""The single-epoch methods whose pass times are summed in the runtime table."""
MANY_OBSERVATIONS = 10
"""``crlb_ratio_10plus`` and the efficiency table use epochs with this many observations."""
OBSERVATION_BIN_EDGES = (3, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000)
"""Bins ``[lo, hi)`` of received observations per epoch (Fig. 10)."""
MIN_BIN_EPOCHS = 30
"""The accuracy figure leaves out bins with fewer epochs."""
MEAN_ABS_PER_SIGMA = np.sqrt(2.0 / np.pi)
"""``E|e| / sigma`` of a zero-mean Gaussian error."""
BURN_IN_S = 300.0
"""Filter accuracy and NEES use the epochs at least this long after the first epoch."""
PAPER_FILTER = "mekf_paper"
"""Liu et al. 2023's MEKF (Euler angles of the NLSE as its observation)."""
PAPER_INPUT = "nlse"
SNR_FILTER = "mekf_snr"
SMOOTHER = "rts_snr"
CONSISTENCY_FILTERS = ("mekf_snr", "usque_snr", "mekf_offsets_snr", "usque_offsets_snr")
"""Filters whose run-averaged NEES is tested."""
REFERENCE_METHODS = ("nlp_truncated", "nlse")
"""Single-frame rows shown beside the filters (independent errors from epoch to epoch)."""
SMOOTHERS = (
    "fg_online",
    "fg_batch",
    "fg_batch_offsets",
    "rts_snr",
    "mekf_snr",
    "mekf_offsets_snr",
    "usque_offsets_snr",
)
"""Rows of the smoother table."""


# ------------------------------------------------------------------ rows ---


def gyro_labels(ctx: ReportContext) -> list[str]:
    """The ``gyro`` labels of the configured ``gyros``, in order."""
    return [gyro_label(g) for g in ctx.parameters.get("gyros", [])]


def _single_frame(rows: pd.DataFrame) -> pd.DataFrame:
    return rows[rows["gyro"] == NO_GYRO] if "gyro" in rows else rows


def _filter_rows(rows: pd.DataFrame) -> pd.DataFrame:
    return rows[rows["gyro"] != NO_GYRO] if "gyro" in rows else rows.iloc[:0]


def _select(rows: pd.DataFrame, method: str, gyro: str | None = None) -> pd.DataFrame:
    keep = rows["method"] == method
    if gyro is not None:
        keep &= rows["gyro"] == gyro
    return rows[keep]


def _valid(rows: pd.DataFrame) -> pd.DataFrame:
    return rows[valid_mask(rows)]


def _ordered(wanted: Sequence[str], rows: pd.DataFrame, column: str = "method") -> list[str]:
    present = set(rows[column])
    return [m for m in wanted if m in present] + sorted(present - set(wanted))


def _epochs(rows: pd.DataFrame) -> pd.DataFrame:
    """One row per (trial, epoch) with the columns every method shares."""
    return rows[rows["method"] == rows["method"].iloc[0]]


def _passes(rows: pd.DataFrame) -> pd.Series:
    """Pass time per trial (the first ``runtime_s`` of each)."""
    return rows.groupby("trial_index")["runtime_s"].first()


def burn_in(ctx: ReportContext) -> float:
    """:data:`BURN_IN_S`, or half the pass when the pass is shorter than twice that."""
    t = ctx.rows["t_s"]
    length = float(t.max() - t.min()) + float(ctx.parameters.get("step_s", 0.0))
    return min(BURN_IN_S, 0.5 * length)


def settled_from(ctx: ReportContext) -> float:
    """The time from which filter epochs count as settled (first epoch + :func:`burn_in`)."""
    return float(ctx.rows["t_s"].min()) + burn_in(ctx)


def _settled(rows: pd.DataFrame, start: float) -> pd.DataFrame:
    return rows[valid_mask(rows) & (rows["t_s"] >= start).to_numpy()]


def _angles(key: str, values: Sequence[float]) -> dict[str, float]:
    """``{key}_{yaw,pitch,roll}`` of three values in Table 2's order."""
    return {f"{key}_{n}": float(v) for (n, _), v in zip(TABLE2_AXES, values, strict=True)}


def _table2_statistics(valid: pd.DataFrame, frame: str) -> dict[str, float]:
    """Signed maxima and RMS in Table 2's order of the body-axis errors (``frame``
    ``"body"``) or the Euler-angle differences (``"Euler"``)."""
    columns = EULER if frame == "Euler" else [f"err_{axis}_deg" for _, axis in TABLE2_AXES]
    return _angles("max", [signed_max(valid[c]) for c in columns]) | _angles(
        "rms", [rms(valid[c]) for c in columns]
    )


def _maxima_and_rms(frame: pd.DataFrame) -> dict[str, pd.Series]:
    names = [n for n, _ in TABLE2_AXES]
    return {
        "max yaw / pitch / roll (deg)": joined(frame, [f"max_{n}" for n in names], ".2f"),
        "RMS yaw / pitch / roll (deg)": joined(frame, [f"rms_{n}" for n in names], ".2f"),
    }


def observation_bin(n_obs: pd.Series) -> pd.Series:
    """Lower edge of the :data:`OBSERVATION_BIN_EDGES` bin of each count (-1 outside them)."""
    edges = np.asarray(OBSERVATION_BIN_EDGES)
    index = np.searchsorted(edges, n_obs.to_numpy(), side="right") - 1
    inside = (index >= 0) & (index < edges.size - 1)
    return pd.Series(np.where(inside, edges[np.clip(index, 0, edges.size - 2)], -1), n_obs.index)


def bin_label(start: int) -> str:
    """``lo-hi`` of the bin starting at ``start``."""
    edges = list(OBSERVATION_BIN_EDGES)
    return f"{start}-{edges[edges.index(start) + 1] - 1}"


# ------------------------------------------------------- single frame ---


def table2_section(ctx: ReportContext, methods: list[str]) -> str:
    """Table 2 with our rows (body axes and Euler differences) and the bounds' RMS."""
    summary = _single_frame(ctx.summary).set_index("method")
    paper = paper_table(PACKAGE, "table2").set_index("method")
    label = paper_label(PACKAGE, "table2")
    rows = []

    def paper_row(name: str) -> dict:
        return {"row": f"{name} ({label})", "errors": "Euler", **paper.loc[name].to_dict()}

    for method in methods:
        if method in PAPER_ROWS:
            rows.append(paper_row(PAPER_ROWS[method]))
        valid = _valid(_select(_single_frame(ctx.rows), method))
        s = summary.loc[method]
        ours = {
            "runtime_s": s["runtime_s"],
            "valid": s["valid_fraction"],
            "RMS / CRLB": s["crlb_ratio"],
            f"RMS / CRLB (>= {MANY_OBSERVATIONS} obs)": s["crlb_ratio_10plus"],
            "RMS / truncated CRLB": s["crlb_ratio_truncated"],
            "wrong minima": s["wrong_minimum_fraction"],
            "checked": s["wrong_minimum_checked"],
        }
        for errors, frame in (("body z/y/x", "body"), ("Euler", "Euler")):
            statistics = _table2_statistics(valid, frame)
            rows.append({"row": method, "errors": errors} | statistics | ours)
    rows.append(paper_row("MEKF"))
    epochs = _epochs(_single_frame(ctx.rows))
    for bound, name in (("bound", "CRLB"), ("bound_truncated", "truncated CRLB")):
        bounded = epochs[finite_bound(epochs, bound)]
        rms_bound = {f"rms_{n}": rms(bounded[f"{bound}_{a}_deg"]) for n, a in TABLE2_AXES}
        rows.append({"row": f"{name}: RMS of sqrt(CRB)", "errors": "body z/y/x"} | rms_bound)
    frame = pd.DataFrame(rows).rename(columns={"runtime_s": "runtime (s)"})
    rest = [
        c for c in frame.columns if c not in ("row", "errors") and c[:4] not in ("max_", "rms_")
    ]
    table = frame[["row", "errors"]].assign(**_maxima_and_rms(frame), **{c: frame[c] for c in rest})
    n_trials = ctx.rows["trial_index"].nunique()
    p = ctx.parameters
    caption = (
        f"Pass of {p['duration_s']:.0f} s at {p['step_s']:g} s x {n_trials} trial(s). Signed "
        "largest error and RMS over all valid epochs and trials, as body-axis components (z / "
        "y / x) and as 3-2-1 Euler-angle differences (what Table 2 tabulates); runtime: mean "
        "pass time; RMS / CRLB: sqrt(mean |e|^2) / sqrt(mean trace CRB), the CRB (eq. 22) at "
        "the true attitude with the received messages; RMS / truncated CRLB: against the CRB "
        "of the threshold-truncated measurements; wrong minima: share of the checked epochs."
        + made_by(ctx.command)
    )
    formats = {"runtime (s)": ".3g", "valid": ".4f", "checked": ".0f"}
    return section(f"{label} beside ours", caption, markdown_table(table, formats, ".3f"))


def runtime_section(ctx: ReportContext, methods: list[str]) -> str:
    """Pass times per method and of the single-epoch methods together."""
    rows = _single_frame(ctx.rows)
    passes = rows.groupby(["method", "trial_index"])["runtime_s"].first()
    statistics = ["size", "mean", "max"]
    table = passes.groupby(level="method").agg(statistics).reindex(methods)
    together = [m for m in SINGLE_EPOCH_METHODS if m in methods]
    if together:
        total = passes[passes.index.get_level_values("method").isin(together)]
        table.loc[" + ".join(together)] = total.groupby(level="trial_index").sum().agg(statistics)
    table = table.reset_index()
    table.columns = ["method", "passes", "mean pass (s)", "slowest pass (s)"]
    caption = (
        f"Wall time of each method's warm-started pass of {ctx.parameters['duration_s']:.0f} s "
        "(compiled functions built beforehand, scenario simulation excluded), over the trials; "
        "the last row sums the single-epoch methods per trial." + made_by(ctx.command)
    )
    return section("Runtime", caption, markdown_table(table, {"passes": ".0f"}, ".2f"))


def efficiency_section(ctx: ReportContext, methods: list[str]) -> str:
    """RMS over both bounds with standard errors on the epochs with many observations."""
    rows = _single_frame(ctx.rows)
    reference = _valid(_select(rows, "nlp")).set_index(["trial_index", "t_s"])
    table = []
    for method in methods:
        chosen = bounded_valid_rows(_select(rows, method))
        many = chosen[chosen["n_obs"] >= MANY_OBSERVATIONS]
        truncated = bounded_valid_rows(many, "bound_truncated")
        entry = {
            "method": method,
            "epochs": len(many),
            "RMS / CRLB": rms_ratio(many),
            "standard error": rms_ratio_standard_error(many),
            "RMS / truncated CRLB": rms_ratio(truncated, "bound_truncated"),
            "truncated standard error": rms_ratio_standard_error(truncated, "bound_truncated"),
            "largest difference from nlp (deg)": np.nan,
        }
        if len(reference) and method != "nlp":
            own = _valid(_select(rows, method)).set_index(["trial_index", "t_s"])
            both = own.index.intersection(reference.index)
            gap = sum(
                (own.loc[both, f"err_{a}_deg"] - reference.loc[both, f"err_{a}_deg"]) ** 2
                for a in AXES
            )
            entry["largest difference from nlp (deg)"] = float(np.sqrt(gap).max())
        table.append(entry)
    caption = (
        f"Over the valid epochs with at least {MANY_OBSERVATIONS} received observations: RMS "
        "over the eq. 22 CRLB and over the CRLB of the truncated measurements, each with its "
        "standard error (delta method); largest epoch-by-epoch distance between the method's "
        "error and the NLP's." + made_by(ctx.command)
    )
    formats = {"largest difference from nlp (deg)": ".3g"}
    return section("Efficiency", caption, markdown_table(pd.DataFrame(table), formats, ".3f"))


def antenna_columns(rows: pd.DataFrame) -> list[str]:
    """The rows' ``n_obs_antenna{i}`` columns, in antenna order (one per configured antenna)."""
    found = [c for c in rows.columns if re.fullmatch(r"n_obs_antenna\d+", c)]
    return sorted(found, key=lambda c: int(c.removeprefix("n_obs_antenna")))


def observations_section(ctx: ReportContext) -> str:
    """The received-message counts per epoch (Fig. 8), the reception threshold's bias and the
    epochs whose messages leave a rotation unobservable."""
    epochs = _epochs(_single_frame(ctx.rows))
    per_antenna = antenna_columns(epochs)
    sparser = epochs[per_antenna].min(axis=1)
    stated = paper_values(PACKAGE)["observations"]
    label = paper_label(PACKAGE, "observations")

    def spread(values: pd.Series) -> str:
        return f"{values.min():.0f} / {values.median():.0f} / {values.max():.0f}"

    table = pd.DataFrame(
        {
            "epochs": [len(epochs)],
            "in the main lobes min / median / max": [spread(epochs["n_visible"])],
            "received min / median / max": [spread(epochs["n_obs"])],
            "received share": [epochs["n_obs"].sum() / epochs["n_visible"].sum()],
            "fewest on one antenna": [sparser.min()],
            f"fewest on one antenna ({label})": [stated["min_per_antenna"]],
            "epochs with fewer than 3 on one antenna": [float(np.mean(sparser < 3))],
            "epochs with an unobservable rotation": [float(np.mean(epochs["n_unobservable"] > 0))],
            "mean SNR bias of the received (dB)": [
                np.average(epochs["snr_bias_db"].fillna(0.0), weights=epochs["n_obs"])
            ],
        }
    )
    traffic, receiver = ctx.parameters["traffic"], ctx.parameters["receiver"]
    caption = (
        f"Per epoch of all trials: aircraft in the main lobes of the {len(per_antenna)} "
        f"antenna(s) ({traffic['n_aircraft']} modelled flights, traffic seed {traffic['seed']}) "
        f"and messages whose measured SNR reaches the {receiver['threshold_db']:g} dB "
        "threshold; the mean measured minus true SNR of the received messages (0 without the "
        "threshold's selection); epochs whose received messages leave a rotation unobservable "
        "(all of them on one antenna or on antennas with parallel boresights: the bound is NaN "
        "on the axes it moves, `unobservable_{x,y,z}` in the rows give its direction)."
        + made_by(ctx.command)
    )
    shares = ("epochs with fewer than 3 on one antenna", "epochs with an unobservable rotation")
    table = markdown_table(table, dict.fromkeys(shares, ".4f"), ".3f")
    return section("Received observations (Liu et al. 2023 Fig. 8)", caption, table)


def observation_bins(ctx: ReportContext, methods: list[str]) -> pd.DataFrame:
    """Per observation-count bin (index: lower edge): epochs, CRLB, mean SNR bias and per
    method ``ratio_{m}``, ``truncated_ratio_{m}`` (RMS over the two bounds) and
    ``mean_abs_deg_{m}`` (mean over epochs and axes of |e|)."""
    rows = _single_frame(ctx.rows)
    epochs = _epochs(rows)
    bins = observation_bin(epochs["n_obs"])
    bounded = epochs[finite_bound(epochs)]
    out = pd.DataFrame({"epochs": bins[bins >= 0].value_counts().sort_index()})
    out.index.name = "received"
    out["crlb_deg"] = np.sqrt(squared_norm(bounded, "bound").groupby(bins).mean())
    out["snr_bias_db"] = epochs.groupby(bins)["snr_bias_db"].mean()
    for method in methods:
        chosen = bounded_valid_rows(_select(rows, method))
        by = observation_bin(chosen["n_obs"])
        out[f"ratio_{method}"] = rms_ratio_by_group(chosen, by)
        truncated = chosen[finite_bound(chosen, "bound_truncated")]
        out[f"truncated_ratio_{method}"] = rms_ratio_by_group(
            truncated, by[truncated.index], "bound_truncated"
        )
        mean_abs = chosen[[f"err_{a}_deg" for a in AXES]].abs().mean(axis=1)
        out[f"mean_abs_deg_{method}"] = mean_abs.groupby(by).mean()
    return out[out.index >= 0]  # an empty table takes the index of what is assigned to it


def bins_section(ctx: ReportContext, methods: list[str]) -> str:
    """Accuracy against the number of received observations (Fig. 10)."""
    bins = observation_bins(ctx, methods)
    table = pd.DataFrame(
        {
            "received observations": [bin_label(b) for b in bins.index],
            "epochs": bins["epochs"].to_numpy(),
            "CRLB RMS (deg)": bins["crlb_deg"].to_numpy(),
            "mean SNR bias (dB)": bins["snr_bias_db"].to_numpy(),
        }
    )
    for method in methods:
        table[f"{method} RMS / CRLB"] = bins[f"ratio_{method}"].to_numpy()
    for method in methods:
        table[f"{method} RMS / truncated CRLB"] = bins[f"truncated_ratio_{method}"].to_numpy()
    if {"deterministic", PAPER_INPUT} <= set(methods):
        table[f"mean abs error deterministic / {PAPER_INPUT}"] = (
            bins["mean_abs_deg_deterministic"] / bins[f"mean_abs_deg_{PAPER_INPUT}"]
        ).to_numpy()
    converged = paper_values(PACKAGE)["convergence"]
    caption = (
        "All trials, bins of received messages per epoch: RMS of sqrt(trace CRB), mean measured "
        "minus true SNR of the received messages, each method's RMS over both bounds, and the "
        "deterministic method's mean absolute error over the NLSE's (equal beyond "
        f"{converged['observations']} observations in {paper_label(PACKAGE, 'convergence')})."
        + made_by(ctx.command)
    )
    return section(
        "Accuracy against the number of received observations (Liu et al. 2023 Fig. 10)",
        caption,
        markdown_table(table, spec=".3f"),
    )


def consistency_section(ctx: ReportContext, methods: list[str]) -> str:
    """NEES, share inside 3 sigma and mean loss of each method's own covariance and objective."""
    rows = _single_frame(ctx.rows)
    table = []
    for method in methods:
        chosen = _select(rows, method)
        summary = error_summary(chosen)
        table.append(
            {
                "method": method,
                "mean NEES": summary["mean_nees"],
                "median NEES": summary["median_nees"],
                "inside 3 sigma on all axes": summary["inside_3_sigma"],
                "mean loss (own objective)": _valid(chosen)["loss"].mean(),
            }
        )
    caption = (
        "NEES e^T P^-1 e against each method's own covariance over its valid epochs (mean 3, "
        "median 2.37 when consistent), share of epochs inside 3 sigma on all three axes (at "
        "least 99.2% when consistent) and the mean of the method's own objective."
        + made_by(ctx.command)
    )
    formats = {"inside 3 sigma on all axes": ".4f", "mean loss (own objective)": ".2f"}
    return section("Consistency", caption, markdown_table(pd.DataFrame(table), formats, ".3f"))


# ------------------------------------------------------------ filters ---


def paper_filter_section(ctx: ReportContext, rows: pd.DataFrame, gyros: list[str]) -> str:
    """Table 2's MEKF beside ``mekf_paper``, and what ``mekf_paper`` makes of its input."""
    start = settled_from(ctx)
    paper = paper_table(PACKAGE, "table2").set_index("method")
    label = paper_label(PACKAGE, "table2")
    settled = f"t >= {start:g} s"
    lines = [
        {"row": f"MEKF ({label})", "epochs": "the hour", "errors": "Euler"}
        | paper.loc["MEKF"].to_dict()
    ]
    for gyro in gyros:
        mekf = _select(rows, PAPER_FILTER, gyro)
        for epochs, subset in (("all", _valid(mekf)), (settled, _settled(mekf, start))):
            for errors, frame in (("body z/y/x", "body"), ("Euler", "Euler")):
                lines.append(
                    {"row": f"{PAPER_FILTER}, gyro {gyro}", "epochs": epochs, "errors": errors}
                    | _table2_statistics(subset, frame)
                    | {"runtime_s": _passes(mekf).mean()}
                )
    nlse = _select(ctx.rows, PAPER_INPUT, NO_GYRO)
    lines.append(
        {"row": f"{PAPER_INPUT} (the observation)", "epochs": settled, "errors": "Euler"}
        | _table2_statistics(_settled(nlse, start), "Euler")
        | {"runtime_s": _passes(nlse).mean()}
    )
    frame = pd.DataFrame(lines)
    table = frame[["row", "epochs", "errors"]].assign(
        **_maxima_and_rms(frame), **{"runtime (s)": frame["runtime_s"]}
    )
    caption = (
        f"{PAPER_FILTER} observes the 3-2-1 Euler angles of the {PAPER_INPUT} solution of each "
        f"epoch with R = ({ctx.parameters['paper_sigma_deg']:g} deg)^2 I; signed largest error "
        "and RMS over all valid epochs and after the burn-in; runtime: mean pass time, the "
        "filter alone." + made_by(ctx.command)
    )
    return section(
        f"{label}'s MEKF beside {PAPER_FILTER}",
        caption,
        markdown_table(table, {"runtime (s)": ".3g"}),
        level=3,
    )


def input_section(ctx: ReportContext, rows: pd.DataFrame, gyros: list[str]) -> str:
    """How ``mekf_paper`` relates to its input: RMS ratio, mean error, own sigma."""
    start = settled_from(ctx)
    paper = paper_table(PACKAGE, "table2").set_index("method")
    rms_paper = paper.loc[:, [f"rms_{n}" for n, _ in TABLE2_AXES]].to_numpy()
    mekf_row, nlse_row = paper.index.get_loc("MEKF"), paper.index.get_loc("NLSE")
    nlse = _settled(_select(ctx.rows, PAPER_INPUT, NO_GYRO), start)
    lines = [
        {"row": f"MEKF / NLSE ({paper_label(PACKAGE, 'table2')})"}
        | _angles("ratio", rms_paper[mekf_row] / rms_paper[nlse_row]),
        {"row": PAPER_INPUT}
        | _angles("mean", nlse[EULER].mean())
        | _angles("std", nlse[EULER].std())
        | _angles("sigma", nlse[SIGMA].median()),
    ]
    for gyro in gyros:
        mekf = _settled(_select(rows, PAPER_FILTER, gyro), start)
        ours, reference = paired(mekf, nlse, EPOCH_KEYS)
        sigma = mekf[SIGMA].mean().to_numpy()
        lines.append(
            {"row": f"{PAPER_FILTER}, gyro {gyro}"}
            | _angles("ratio", [rms(ours[c]) / rms(reference[c]) for c in EULER])
            | _angles("mean", mekf[EULER].mean())
            | _angles("std", mekf[EULER].std())
            | _angles("sigma", sigma)
            | _angles("over", sigma / rms_paper[mekf_row])
            | {"mean NEES": mekf["nees"].mean(), "inside 3 sigma": inside_3_sigma(mekf)}
        )
    frame = pd.DataFrame(lines)
    columns = {
        "RMS / nlse RMS": "ratio",
        "mean error": "mean",
        "standard deviation": "std",
        "own sigma": "sigma",
        "own sigma / Table 2 MEKF RMS": "over",
    }
    table = frame[["row"]].assign(
        **{
            f"{title} yaw / pitch / roll": joined(
                frame, [f"{key}_{n}" for n, _ in TABLE2_AXES], ".2f"
            )
            for title, key in columns.items()
        }
    )
    table = table.join(frame[["mean NEES", "inside 3 sigma"]])
    caption = (
        f"Settled epochs (t >= {start:g} s), Euler-angle differences (deg): {PAPER_FILTER}'s RMS "
        f"over the {PAPER_INPUT}'s on the same epochs (the paper's ratio from Table 2), mean "
        f"and standard deviation of the errors, own sigma (median for the {PAPER_INPUT}, eq. 22 "
        "at the estimate widened by the selection bias; mean for the filter, whose reported "
        "covariance considers its input's, docs/filters.md) and its ratio to Table 2's MEKF RMS."
        + made_by(ctx.command)
    )
    formats = {"mean NEES": ".2f", "inside 3 sigma": ".3f"}
    return section(
        f"{PAPER_FILTER} and its input", caption, markdown_table(table, formats), level=3
    )


def comparison_section(ctx: ReportContext, rows: pd.DataFrame, gyros: list[str]) -> str:
    """Every filter per gyro after the burn-in, with the single-frame references."""
    start = settled_from(ctx)
    lines = []
    references = [m for m in REFERENCE_METHODS if m in set(ctx.rows["method"])]
    groups = [(NO_GYRO, m, _select(ctx.rows, m, NO_GYRO)) for m in references]
    for gyro in gyros:
        on_gyro = rows[rows["gyro"] == gyro]
        groups += [
            (gyro, m, _select(on_gyro, m))
            for m in _ordered(ctx.parameters.get("filters", []), on_gyro)
        ]
    for gyro, method, every in groups:
        chosen = _settled(every, start)
        ours, reference = paired(
            chosen, _settled(_select(rows, PAPER_FILTER, gyro), start), EPOCH_KEYS
        )
        filtered = gyro != NO_GYRO
        runtime = _passes(every)
        counts = ("n_gated", "n_unpredictable", "n_used")
        line = error_summary(chosen) | {
            "gyro": gyro,
            "method": method,
            "ratio": total_rms(ours) / total_rms(reference) if len(ours) else np.nan,
            "nees_full": chosen["nees_full"].mean() if filtered else np.nan,
            "counts": " / ".join(f"{int(every[c].sum()):,}" for c in counts) if filtered else "-",
            "runtime": f"{runtime.mean():.2f} ({runtime.max():.2f})",
            "valid": float(np.mean(valid_mask(every))),
        }
        for axis in AXES:
            line[f"bias_{axis}"] = rms(chosen[f"bias_err_{axis}_deg_h"]) if filtered else np.nan
        lines.append(line)
    frame = pd.DataFrame(lines)
    table = frame[["gyro", "method"]].assign(
        **{
            "RMS roll / pitch / yaw (deg)": joined(frame, [f"rms_{a}" for a in AXES]),
            "RMS / mekf_paper RMS": frame["ratio"],
            "mean error roll / pitch / yaw (deg)": joined(frame, [f"mean_{a}" for a in AXES]),
            "mean NEES (3)": frame["mean_nees"],
            "mean NEES (6)": frame["nees_full"],
            "inside 3 sigma, all axes": frame["inside_3_sigma"],
            "bias error RMS x / y / z (deg/h)": joined(frame, [f"bias_{a}" for a in AXES], ".1f"),
            "gated / unpredictable / used observations": frame["counts"],
            "runtime (s per pass), mean (max)": frame["runtime"],
            "valid": frame["valid"],
        }
    )
    caption = (
        f"Valid epochs at t >= {start:g} s of every trial ({burn_in(ctx):g} s burn-in from the "
        f"prior, {ctx.parameters.get('initial_sigma_deg', np.nan):g} deg per axis); the RMS "
        "ratio over the (trial, epoch) pairs valid in both rows; NEES of the attitude (3) and "
        "of attitude and bias (6); observations over the whole pass (gated by the innovation "
        "gate, left out outside the predicted main lobe, used); gyro none: single-frame "
        "references, whose errors are independent from epoch to epoch." + made_by(ctx.command)
    )
    formats = {"mean NEES (3)": ".2f", "mean NEES (6)": ".2f", "valid": ".4f"}
    return section("Filters compared", caption, markdown_table(table, formats, ".3f"), level=3)


def nees_section(ctx: ReportContext, rows: pd.DataFrame, gyros: list[str]) -> str:
    """The time-averaged run-averaged NEES of the SNR filters against its chi-square interval."""
    start = settled_from(ctx)
    trials = rows["trial_index"].nunique()
    lo, hi = nees_interval(trials)
    lines = []
    for method in CONSISTENCY_FILTERS:
        for gyro in gyros:
            averaged = run_averaged_nees(_settled(_select(rows, method, gyro), start), "t_s")
            if len(averaged):
                lines.append(
                    {
                        "method": method,
                        "gyro": gyro,
                        "epochs": len(averaged),
                        "run- and time-averaged NEES": averaged.mean(),
                        "95% interval": f"[{lo:.3f}, {hi:.3f}]",
                        "epochs inside": float(((averaged >= lo) & (averaged <= hi)).mean()),
                    }
                )
    caption = (
        f"Per settled epoch valid in all {trials} trial(s), the attitude NEES averaged over the "
        "trials, then over the epochs, against the two-sided 95% interval of chi2(3M)/M for M "
        "trials; epochs inside: share of epochs whose trial average lies in it. "
        "`python -m attopt.experiments.benchmarks.filters` runs it over 100 trials."
        + made_by(ctx.command)
    )
    table = pd.DataFrame(lines)
    table = markdown_table(table, spec=".3f")
    return section("Run-averaged NEES", caption, table, level=3) if lines else ""


def smoother_section(ctx: ReportContext, rows: pd.DataFrame, gyros: list[str]) -> str:
    """Smoothers, the RTS pass and the MEKF against ``mekf_paper`` and the posterior bound."""
    start = settled_from(ctx)
    lines = []
    for gyro in gyros:
        paper = _settled(_select(rows, PAPER_FILTER, gyro), start)
        for method in SMOOTHERS:
            chosen = _settled(_select(rows, method, gyro), start)
            if not len(chosen):
                continue
            ours, reference = paired(chosen, paper, EPOCH_KEYS)
            total, bound = total_rms(chosen), total_rms(chosen, "pbound")
            lines.append(
                {
                    "gyro": gyro,
                    "method": method,
                    "RMS (deg)": total,
                    "bound (deg)": bound,
                    "RMS / bound": total / bound,
                    "RMS / mekf_paper": total_rms(ours) / total_rms(reference)
                    if len(ours)
                    else np.nan,
                    "mean NEES (3)": chosen["nees"].mean(),
                    "runtime (s)": _passes(chosen).mean(),
                }
            )
    caption = (
        f"Total RMS over the valid epochs at t >= {start:g} s; bound: RMS over the same epochs "
        "of the posterior Cramer-Rao bound of the whole pass (every received SNR, offsets not "
        "modelled); transmitter power offsets in the data: "
        f"{ctx.parameters['traffic']['power_offset_sigma_db']:g} dB (sigma); runtime: mean pass "
        "time, fg_batch's including the pass it starts from." + made_by(ctx.command)
    )
    formats = {"RMS / bound": ".2f", "mean NEES (3)": ".2f", "runtime (s)": ".1f"}
    table = markdown_table(pd.DataFrame(lines), formats, ".3f")
    return section("Factor-graph smoothers", caption, table, level=3)


def filter_section(ctx: ReportContext) -> str:
    """The gyro-aided filters (empty without filter rows)."""
    rows = _filter_rows(ctx.rows)
    if not len(rows):
        return ""
    gyros = _ordered(gyro_labels(ctx), rows, "gyro")
    paper_gyros = [g for g in gyros if len(_select(rows, PAPER_FILTER, g))]
    parts = [
        paper_filter_section(ctx, rows, paper_gyros) if paper_gyros else "",
        input_section(ctx, rows, paper_gyros) if paper_gyros else "",
        comparison_section(ctx, rows, gyros),
        nees_section(ctx, rows, gyros),
    ]
    if any(len(_select(rows, m)) for m in SMOOTHERS[:3]):
        parts.append(smoother_section(ctx, rows, gyros))
    caption = (
        f"Filters and smoothers on the received SNRs with a simulated gyro per model "
        f"({', '.join(f'`{g}`' for g in gyros)}; docs/filters.md)." + made_by(ctx.command)
    )
    return section("Gyro-aided filters", caption, *parts)


# ------------------------------------------------------------ figures ---


def _observations_figure(ctx: ReportContext) -> str:
    epochs = first_trial(_epochs(_single_frame(ctx.rows)))
    figure, ax = plt.subplots(figsize=(9, 4))
    per_antenna = antenna_columns(epochs)
    lines = [
        (column, f"C{i + 1}", f"antenna {i + 1} (received)") for i, column in enumerate(per_antenna)
    ]
    lines += [("n_obs", "C0", "total (received)"), ("n_visible", "0.6", "total in main lobes")]
    for column, colour, label in lines:
        ax.plot(epochs["t_s"], epochs[column], color=colour, lw=0.7, label=label)
    ax.set(yscale="log", xlabel="t (s)", ylabel="observations per epoch")
    threshold = ctx.parameters["receiver"]["threshold_db"]
    ax.set_title(f"Observations (SNR >= {threshold:g} dB), first trial")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", lw=0.3)
    return save_figure(figure, ctx.out_dir, "observations.png")


def _error_vs_observations_figure(ctx: ReportContext, methods: list[str]) -> str | None:
    """Fig. 10's analogue, or None without a bin of :data:`MIN_BIN_EPOCHS` bounded epochs
    (e.g. one antenna: no finite bound)."""
    rows = _single_frame(ctx.rows)
    epochs = _epochs(rows)
    epochs = epochs[finite_bound(epochs)]
    counts = observation_bin(epochs["n_obs"]).value_counts()
    filled = set(counts.index[(counts.index >= 0) & (counts >= MIN_BIN_EPOCHS)])
    if not filled:
        return None
    figure, axes = plt.subplots(1, 3, figsize=(13, 4.4), sharex=True)
    for ax, axis in zip(axes, AXES, strict=True):
        for method, style in zip(methods, ("o-", "s--", "^:", "v-."), strict=False):
            chosen = bounded_valid_rows(_select(rows, method))
            by = observation_bin(chosen["n_obs"])
            line = chosen[by.isin(filled)].groupby(by[by.isin(filled)])
            ax.plot(
                line["n_obs"].mean(),
                line[f"err_{axis}_deg"].apply(lambda e: e.abs().mean()),
                style,
                mfc="none",
                label=method,
            )
        by = observation_bin(epochs["n_obs"])
        bound = epochs[by.isin(filled)].groupby(by[by.isin(filled)])
        for column, style, label in (
            ("bound", "k--", "CRLB"),
            ("bound_truncated", "k:", "truncated CRLB"),
        ):
            ax.plot(
                bound["n_obs"].mean(),
                MEAN_ABS_PER_SIGMA * bound[f"{column}_{axis}_deg"].mean(),
                style,
                label=f"{label} x sqrt(2/pi)",
            )
        ax.set(xscale="log", yscale="log", xlabel="received observations per epoch (bin mean)")
        for scale in (ax.xaxis, ax.yaxis):
            scale.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
            scale.set_major_formatter(ticker.FormatStrFormatter("%g"))
            scale.set_minor_formatter(ticker.NullFormatter())
        ax.set_title(f"mean |error| (deg), axis {axis}")
        ax.grid(True, which="both", lw=0.3)
    axes[0].legend(fontsize=7)
    return save_figure(figure, ctx.out_dir, "error_vs_observations.png")


def figures(ctx: ReportContext, methods: list[str]) -> list[str]:
    """Write the figures (Figs. 8-10 analogues, the filters' errors and bias errors)."""
    names = [_observations_figure(ctx)] if methods else []
    single = first_trial(_single_frame(ctx.rows))
    for method in methods:
        figure = error_figure(
            {method: single[single["method"] == method]},
            f"{method}: body-axis error, first trial",
            time="t_s",
        )
        names.append(save_figure(figure, ctx.out_dir, f"error_{method}.png"))
    accuracy = _error_vs_observations_figure(ctx, methods) if methods else None
    if accuracy is not None:
        names.append(accuracy)
    rows = _filter_rows(ctx.rows)
    start = settled_from(ctx)
    burn = [(float(ctx.rows["t_s"].min()), start, "burn-in")]
    for gyro in _ordered(gyro_labels(ctx), rows, "gyro") if len(rows) else []:
        first = first_trial(rows[rows["gyro"] == gyro])
        drawn = {
            m: _valid(_select(first, m))
            for m in (PAPER_FILTER, SNR_FILTER, SMOOTHER)
            if len(_select(first, m))
        }
        if drawn:
            title = f"gyro {gyro}: body-axis error, first trial (y fitted to t >= {start:g} s)"
            figure = error_figure(drawn, title, time="t_s", spans=burn, fit_from=start)
            names.append(save_figure(figure, ctx.out_dir, f"filter_errors_{gyro}.png"))
        if SNR_FILTER in drawn:
            figure = error_figure(
                {SNR_FILTER: drawn[SNR_FILTER]},
                f"{SNR_FILTER}, gyro {gyro}: gyro-bias error, first trial",
                values=[f"bias_err_{a}_deg_h" for a in AXES],
                sigmas=[f"bias_sigma_{a}_deg_h" for a in AXES],
                unit="deg/h",
                names=[f"bias {a}" for a in AXES],
                time="t_s",
                spans=burn,
                fit_from=start,
            )
            names.append(save_figure(figure, ctx.out_dir, f"gyro_bias_{gyro}.png"))
    return names


def report(ctx: ReportContext) -> str:
    """Markdown: the single-frame tables, the filter tables, integrity, figures."""
    single = _single_frame(ctx.rows)
    methods = _ordered(ctx.parameters.get("methods", []), single) if len(single) else []
    parts = []
    if methods:
        parts += [
            table2_section(ctx, methods),
            runtime_section(ctx, methods),
            efficiency_section(ctx, methods),
            observations_section(ctx),
            bins_section(ctx, methods),
            consistency_section(ctx, methods),
        ]
    keys = ["gyro", "method"] if "gyro" in ctx.rows else ["method"]
    parts += [
        filter_section(ctx),
        integrity_section(ctx.rows, keys, ctx.command),
        section("Figures", image_links(figures(ctx, methods))),
    ]
    return document(parts)
