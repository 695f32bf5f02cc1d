"""Report of ``doa-ground``: seed 003 Tables 1 and 2 beside ours, a one-line-per-setting
summary, the smoother target, the estimators' consistency (NEES), runtimes and
convergence.

Pooling:

* DOA RMSEs pool every accepted MUSIC estimate of every trial (the ``music``
  row of a trial holds its counts and mean squared errors, weighted by the
  accepted count; the CRB by the count of estimates).
* Attitude RMSEs follow seed 003 eq. 34: one root mean square over all
  ``settled`` rows of all trials of a setting, valid rows only (NaN rows of a
  method without a solution do not count).  Yaw, roll and pitch are the 3-2-1
  Euler-angle differences; the total is ``sqrt(mean(err_x^2 + err_y^2 +
  err_z^2))`` of the body-axis errors, and the bound's total the same of
  ``pbound_*`` (posterior bound of a pass) or ``bound_*`` (single-epoch CRB),
  and ``crb_*`` (the EKF's and RTS's bound with ``Q = 0``) likewise.
* The smoother-versus-EKF table pools, per setting, only the trials in which
  the :data:`SUBSET_METHODS` ran (all trials if none ran in that setting),
  the same trials for every method of the table.
* Runtimes: mean over passes (one ``runtime_s`` per trial and method).

The convergence figure (seed 003 Figs. 6-7) draws the first trial of the
setting nearest to the seed's first simulation (0 dB, ``L = 100``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from scipy.stats import chi2

from attopt.experiments.experiment import ReportContext
from attopt.solvers.doa.ekf import PROCESS_NOISE

# Seed 003 Tables 1-2: (snr_db, L) -> RMSE theta, phi, yaw, roll, pitch (deg).
SEED003_TABLES: dict[tuple[float, int], tuple[float, float, float, float, float]] = {
    (-14.0, 100): (11.118, 68.128, 7.397, 3.662, 1.732),
    (-12.0, 100): (4.106, 17.337, 0.652, 0.177, 0.457),
    (-10.0, 100): (1.518, 1.307, 0.130, 0.079, 0.215),
    (-8.0, 100): (0.921, 0.791, 0.109, 0.078, 0.157),
    (-6.0, 100): (0.595, 0.534, 0.094, 0.071, 0.111),
    (-2.0, 100): (0.354, 0.334, 0.084, 0.060, 0.094),
    (0.0, 100): (0.315, 0.308, 0.083, 0.061, 0.094),
    (14.0, 100): (0.287, 0.289, 0.084, 0.060, 0.093),
    (0.0, 1): (8.354, 51.089, 15.956, 10.071, 6.852),
    (0.0, 10): (0.781, 0.684, 0.099, 0.070, 0.146),
    (0.0, 20): (0.408, 0.385, 0.086, 0.064, 0.100),
    (0.0, 50): (0.342, 0.326, 0.084, 0.062, 0.091),
    (0.0, 1000): (0.287, 0.289, 0.084, 0.062, 0.093),
}
SEED003_TABLE1_SNAPSHOTS = 100
SEED003_TABLE2_SNR_DB = 0.0
GYRO_FILTERS = ("mekf", "fg_batch")
"""Default ``filters``: the gyro-aided MEKF and the factor-graph smoother."""
SMOOTHER = "fg_batch"
BATCH_LS = "bls_seed003"
"""Whole-pass batch least squares over the seed's dynamics (``Q = 0``)."""
SUBSET_METHODS = (BATCH_LS, *GYRO_FILTERS)
"""Methods that run only in the first ``filter_trials`` trials of a setting."""
SMOOTHER_TARGET = 0.5
"""Issue target: a smoother's settled RMS at most half the seed's EKF's on the same data."""
ATTITUDE_THRESHOLD_DEG = 0.5
"""Seed 003 sec. 6: attitude errors converge to 0.5 deg (within 1500 s)."""
RATE_THRESHOLD_DEG_S = 0.1
"""Seed 003 sec. 6: rate errors reach 0.1 deg/s (in about 1000 s)."""
EULER = ("yaw", "roll", "pitch")
AXES = ("x", "y", "z")
SETTING = ["snr_db", "snapshots"]
KEYS = [*SETTING, "method"]


def ekf_method(q: float) -> str:
    """Method name of the seed's EKF with process noise ``q``."""
    return f"ekf_seed003_q{q:.0e}"


def rts_method(q: float) -> str:
    """Method name of the RTS smoother over the EKF with process noise ``q``."""
    return f"rts_seed003_q{q:.0e}"


def process_noises(parameters: Mapping[str, Any]) -> list[float]:
    """The EKFs' ``Q`` values; the first is the seed's (default its 1e-9 alone)."""
    return [float(q) for q in np.atleast_1d(parameters.get("process_noise", PROCESS_NOISE))]


def attitude_methods(rows: pd.DataFrame, parameters: Mapping[str, Any]) -> list[str]:
    """Attitude methods present in ``rows``: EKFs and RTSs in ``process_noise`` order,
    the batch least squares, ``wahba``, then the gyro-aided ``filters``."""
    qs = process_noises(parameters)
    candidates = [
        *map(ekf_method, qs),
        *map(rts_method, qs),
        BATCH_LS,
        "wahba",
        *parameters.get("filters", GYRO_FILTERS),
    ]
    present = set(rows["method"])
    return [m for m in dict.fromkeys(candidates) if m in present]


def doa_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per ``(snr_db, snapshots)``: pooled DOA RMSE, RMS CRB at the truth and acceptance."""
    music = rows[rows["method"] == "music"].copy()
    weight = music["doa_accepted"]
    music["theta_sq"] = music["doa_theta_mse_deg2"].fillna(0.0) * weight
    music["phi_sq"] = music["doa_phi_mse_deg2"].fillna(0.0) * weight
    music["crb_theta_sq"] = music["doa_crb_theta_deg2"] * music["doa_count"]
    music["crb_phi_sq"] = music["doa_crb_phi_deg2"] * music["doa_count"]
    sums = music.groupby(SETTING)[
        ["theta_sq", "phi_sq", "crb_theta_sq", "crb_phi_sq", "doa_accepted", "doa_count"]
    ].sum()
    return pd.DataFrame(
        {
            "theta_rmse_deg": np.sqrt(sums["theta_sq"] / sums["doa_accepted"]),
            "phi_rmse_deg": np.sqrt(sums["phi_sq"] / sums["doa_accepted"]),
            "crb_theta_deg": np.sqrt(sums["crb_theta_sq"] / sums["doa_count"]),
            "crb_phi_deg": np.sqrt(sums["crb_phi_sq"] / sums["doa_count"]),
            "accepted": sums["doa_accepted"] / sums["doa_count"],
        }
    )


def _squared_norm(rows: pd.DataFrame, prefix: str) -> pd.Series:
    """``x^2 + y^2 + z^2`` of the ``{prefix}_{axis}_deg`` columns (NaN if any is NaN or absent)."""
    columns = [f"{prefix}_{a}_deg" for a in AXES]
    if not set(columns) <= set(rows.columns):
        return pd.Series(np.nan, index=rows.index)
    return (rows[columns] ** 2).sum(axis=1, min_count=len(columns))


def attitude_table(rows: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per ``(snr_db, snapshots, method)``: settled Euler and total RMSEs (eq. 34 pooling,
    valid rows), the bound's total RMS, RMS / bound, valid share and contributing trials."""
    settled = rows[(rows["phase"] == "settled") & rows["method"].isin(methods)]
    valid = settled["valid"].astype(bool)
    good = settled[valid]
    squares = pd.DataFrame(
        {
            **{f"{n}_rmse_deg": good[f"euler_{n}_err_deg"] ** 2 for n in EULER},
            "total_rmse_deg": _squared_norm(good, "err"),
            "bound_total_deg": _squared_norm(good, "pbound").fillna(_squared_norm(good, "bound")),
            "crb_total_deg": _squared_norm(good, "crb"),
        }
    )
    share = valid.groupby([settled[k] for k in KEYS]).mean()
    table = np.sqrt(squares.groupby([good[k] for k in KEYS]).mean()).reindex(share.index)
    table["ratio"] = table["total_rmse_deg"] / table["bound_total_deg"]
    table["valid"] = share
    table["trials"] = good.groupby(KEYS)["trial_index"].nunique().reindex(share.index).fillna(0)
    return table


def shared_trials(rows: pd.DataFrame) -> pd.DataFrame:
    """The rows of the trials in which the :data:`SUBSET_METHODS` ran, per setting (every
    trial of a setting in which none ran)."""
    in_subset = rows["method"].isin(SUBSET_METHODS)
    in_trial = in_subset.groupby([rows[k] for k in [*SETTING, "trial_index"]]).transform("any")
    in_setting = in_subset.groupby([rows[k] for k in SETTING]).transform("any")
    return rows[in_trial | ~in_setting]


def runtime_table(rows: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per method: number of passes with a ``runtime_s`` and their mean runtime (s)."""
    timed = rows[rows["method"].isin(methods) & rows["runtime_s"].notna()]
    passes = timed.groupby([*KEYS, "trial_index"])["runtime_s"].first()
    table = passes.groupby(level="method").agg(["count", "mean"])
    return table.reindex([m for m in methods if m in table.index])


def convergence_times(curve: pd.DataFrame) -> tuple[float, float]:
    """First times after which every Euler error stays within 0.5 deg and every rate error
    within 0.1 deg/s (NaN if never)."""
    attitude = (
        curve[[f"euler_{n}_err_deg" for n in EULER]].abs().max(axis=1) > ATTITUDE_THRESHOLD_DEG
    )
    rate = curve[[f"rate_err_{a}_deg_s" for a in AXES]].abs().max(axis=1) > RATE_THRESHOLD_DEG_S
    return _settling_time(curve["t"], attitude), _settling_time(curve["t"], rate)


def _settling_time(t: pd.Series, outside: pd.Series) -> float:
    if outside.iloc[-1]:
        return float("nan")
    last = np.flatnonzero(outside.to_numpy())
    return float(t.iloc[last[-1] + 1]) if last.size else float(t.iloc[0])


def convergence_trial(
    rows: pd.DataFrame, methods: Sequence[str]
) -> tuple[dict[str, pd.DataFrame], float, int]:
    """Rows (sorted by ``t``) per method of the first trial of the setting nearest 0 dB,
    ``L = 100``, with that setting's SNR and ``L``."""
    attitude = rows[rows["method"].isin(methods)]
    settings = attitude[SETTING].drop_duplicates()
    distance = settings["snr_db"].abs() + np.abs(np.log10(settings["snapshots"] / 100.0))
    snr, snapshots = settings.iloc[int(np.argmin(distance.to_numpy()))]
    chosen = attitude[(attitude["snr_db"] == snr) & (attitude["snapshots"] == snapshots)]
    first = chosen[chosen["trial_index"] == chosen["trial_index"].min()].sort_values("t")
    return dict(tuple(first.groupby("method"))), float(snr), int(snapshots)


def _figure(
    curves: Mapping[str, pd.DataFrame], qs: Sequence[float], title: str, path: Path
) -> None:
    """Top: Euler errors of the seed's-Q EKF and (dashed) the lowest-Q EKF, total errors of
    the lowest-Q RTS, ``fg_batch`` and the batch least squares; bottom: the EKFs' rate
    errors."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    drawn = dict.fromkeys([qs[0], min(qs)])  # the seed's Q, then the lowest if another
    for q, style in zip(drawn, ("-", "--"), strict=False):
        curve = curves.get(ekf_method(q))
        if curve is None:
            continue
        for name, color in zip(EULER, ("C0", "C1", "C2"), strict=True):
            top.plot(
                curve["t"],
                curve[f"euler_{name}_err_deg"],
                style,
                color=color,
                label=f"{name}, EKF Q={q:.0e}",
            )
        for axis, color in zip(AXES, ("C0", "C1", "C2"), strict=True):
            bottom.plot(
                curve["t"],
                curve[f"rate_err_{axis}_deg_s"],
                style,
                color=color,
                label=f"omega_{axis}, EKF Q={q:.0e}",
            )
    for method, color in ((rts_method(min(qs)), "C3"), (SMOOTHER, "C4"), (BATCH_LS, "C5")):
        if method in curves:
            curve = curves[method]
            total = np.sqrt(_squared_norm(curve, "err"))
            top.plot(curve["t"], total, color=color, label=f"{method} total")
    top.set_ylabel("attitude error (deg)")
    top.set_yscale("symlog", linthresh=0.1)
    top.legend(fontsize="small", ncol=2)
    bottom.set_ylabel("rate error (deg/s)")
    bottom.set_yscale("symlog", linthresh=0.01)
    bottom.set_xlabel("t (s)")
    bottom.legend(fontsize="small", ncol=2)
    top.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _f(x: float | None, spec: str = ".3f") -> str:
    """``x`` formatted with ``spec``; ``-`` for a missing or non-finite value."""
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def _since(time_s: float) -> str:
    return f"from t = {time_s:.0f} s" if np.isfinite(time_s) else "not at the end of the pass"


def _verdict(ratio: float) -> str:
    if not np.isfinite(ratio):
        return "-"
    return f"{ratio:.2f} ({'met' if ratio <= SMOOTHER_TARGET else 'missed'})"


def _entry(table: pd.DataFrame, key: tuple[Any, ...]) -> pd.Series:
    """Row ``key`` of ``table``, or NaN in every column."""
    if key in table.index:
        return table.loc[key]
    return pd.Series(np.nan, index=table.columns)


def _table_settings(
    settings: pd.DataFrame, fixed: str, value: float, swept: str, values: Sequence[float] | None
) -> list[tuple[float, int]]:
    """Settings with ``fixed == value`` (and ``swept`` in ``values`` if given), by ``swept``."""
    chosen = settings[settings[fixed] == value]
    if values is not None:
        chosen = chosen[chosen[swept].isin([float(v) for v in values])]
    return [(float(s), int(n)) for s, n in chosen.sort_values(swept)[SETTING].to_numpy()]


def _seed_table(
    title: str,
    settings: Sequence[tuple[float, int]],
    doa: pd.DataFrame,
    attitude: pd.DataFrame,
    methods: Sequence[str],
) -> list[str]:
    """One of seed 003's tables: the DOA table and the attitude table beside the seed's."""
    lines = [
        "",
        f"## {title}",
        "",
        "| SNR dB | L | theta RMSE (seed) | phi RMSE (seed) | CRB theta / phi | accepted |",
        "|---|---|---|---|---|---|",
    ]
    for snr, snapshots in settings:
        seed = SEED003_TABLES.get((snr, snapshots), (np.nan,) * 5)
        d = _entry(doa, (snr, snapshots))
        lines.append(
            f"| {snr:g} | {snapshots} | {_f(d['theta_rmse_deg'])} ({_f(seed[0])}) "
            f"| {_f(d['phi_rmse_deg'])} ({_f(seed[1])}) "
            f"| {_f(d['crb_theta_deg'])} / {_f(d['crb_phi_deg'])} | {_f(d['accepted'])} |"
        )
    lines += [
        "",
        "| SNR dB | L | method | yaw | roll | pitch | seed 003 EKF yaw / roll / pitch "
        "| total RMS | bound RMS | RMS / bound | CRB (Q = 0) | valid | trials |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for snr, snapshots in settings:
        seed = SEED003_TABLES.get((snr, snapshots), (np.nan,) * 5)
        for method in methods:
            a = _entry(attitude, (snr, snapshots, method))
            beside = " / ".join(map(_f, seed[2:])) if method.startswith("ekf_") else ""
            lines.append(
                f"| {snr:g} | {snapshots} | {method} "
                f"| {' | '.join(_f(a[f'{n}_rmse_deg']) for n in EULER)} | {beside} "
                f"| {_f(a['total_rmse_deg'])} | {_f(a['bound_total_deg'])} "
                f"| {_f(a['ratio'], '.2f')} | {_f(a['crb_total_deg'], '.4f')} "
                f"| {_f(a['valid'])} | {_f(a['trials'], '.0f')} |"
            )
    return lines


def _summary_lines(
    settings: Sequence[tuple[float, int]],
    doa: pd.DataFrame,
    attitude: pd.DataFrame,
    qs: Sequence[float],
) -> list[str]:
    """One line per setting: the DOA RMSEs against the CRB, the EKFs' Euler RMSEs at the
    seed's and the lowest ``Q`` (the seed's values beside the lowest), the lowest-``Q``
    RTS, the batch least squares and the whole pass's ``Q = 0`` CRB (totals)."""
    seed_q, low = qs[0], min(qs)
    lines = [
        "",
        "## Summary",
        "",
        "DOA RMSE / RMS CRB (deg) and the share of estimates accepted; settled attitude RMSEs "
        "(deg): the EKFs' yaw, roll, pitch (seed 003 in brackets), the total RMS of the RTS "
        f"pass and of `{BATCH_LS}` (in the trials it ran in), and the total of the CRB "
        "(Q = 0) of the whole pass (the RTS rows' `crb_*`, the bound of the smoothers and of "
        "the batch least squares).",
        "",
        "| SNR dB | L | theta / CRB (seed) | phi / CRB (seed) | accepted "
        f"| EKF Q = {seed_q:.0e}: yaw, roll, pitch "
        + (f"| EKF Q = {low:.0e}: yaw, roll, pitch (seed) " if low != seed_q else "")
        + f"| RTS Q = {low:.0e} | {BATCH_LS} | CRB (Q = 0) |",
        "|---|---|---|---|---|---|" + ("---|" if low != seed_q else "") + "---|---|---|",
    ]
    for snr, snapshots in settings:
        seed = SEED003_TABLES.get((snr, snapshots), (np.nan,) * 5)
        d = _entry(doa, (snr, snapshots))
        euler = {
            q: ", ".join(
                _f(_entry(attitude, (snr, snapshots, ekf_method(q)))[f"{n}_rmse_deg"])
                for n in EULER
            )
            for q in (seed_q, low)
        }
        cells = [
            f"{_f(d['theta_rmse_deg'])} / {_f(d['crb_theta_deg'])} ({_f(seed[0])})",
            f"{_f(d['phi_rmse_deg'])} / {_f(d['crb_phi_deg'])} ({_f(seed[1])})",
            _f(d["accepted"]),
            euler[seed_q],
        ]
        if low != seed_q:
            cells.append(f"{euler[low]} ({', '.join(map(_f, seed[2:]))})")
        cells += [
            _f(_entry(attitude, (snr, snapshots, rts_method(low)))["total_rmse_deg"]),
            _f(_entry(attitude, (snr, snapshots, BATCH_LS))["total_rmse_deg"], ".4f"),
            _f(_entry(attitude, (snr, snapshots, rts_method(low)))["crb_total_deg"], ".4f"),
        ]
        lines.append(f"| {snr:g} | {snapshots} | " + " | ".join(cells) + " |")
    return lines


def _smoother_lines(rows: pd.DataFrame, methods: Sequence[str], qs: Sequence[float]) -> list[str]:
    """Total settled RMS of the smoothers against each EKF on the trials the
    :data:`SUBSET_METHODS` ran in, with the ``Q = 0`` CRB."""
    shared = shared_trials(rows)
    table = attitude_table(shared, methods)
    others = [m for m in (BATCH_LS, SMOOTHER) if m in methods]
    trials = shared.groupby(SETTING)["trial_index"].nunique()
    lines = [
        "",
        "## Smoother versus the seed's EKF on the same data",
        "",
        f"Issue target: a smoother's total settled RMS at most {SMOOTHER_TARGET:g} times the "
        f"EKF's. Per setting only the trials in which `{'`, `'.join(SUBSET_METHODS)}` ran (all "
        "trials where none did), the same trials for every column; RTS is the smoother over "
        f"the EKF of the same Q, `{BATCH_LS}` the whole-pass batch least squares over the "
        "seed's dynamics (Q = 0), whose Cramer-Rao bound is the CRB column (the whole "
        "pass's, the RTS rows' `crb_*`). RMS in deg.",
        "",
        "| SNR dB | L | trials | Q | EKF | "
        + " | ".join(f"{label} | {label} / EKF" for label in ["RTS", *others])
        + " | CRB (Q = 0) |",
        "|---|---|---|---|---|" + "---|---|" * (1 + len(others)) + "---|",
    ]
    for (snr, snapshots), count in trials.items():
        for q in qs:
            ekf = _entry(table, (snr, snapshots, ekf_method(q)))["total_rmse_deg"]
            crb = _entry(table, (snr, snapshots, rts_method(q)))["crb_total_deg"]
            cells = []
            for name in [rts_method(q), *others]:
                rms = _entry(table, (snr, snapshots, name))["total_rmse_deg"]
                cells += [_f(rms), _verdict(rms / ekf)]
            lines.append(
                f"| {snr:g} | {snapshots} | {count} | {q:.0e} | {_f(ekf)} | "
                + " | ".join(cells)
                + f" | {_f(crb, '.4f')} |"
            )
    return lines


NEES_PROBABILITY = 0.9999
"""Quantile of ``chi2(3)`` above which a row's attitude NEES counts as inconsistent."""


def consistency_table(rows: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per ``(snr_db, snapshots, method)`` and phase: mean and median attitude NEES of the
    valid rows and their share above the ``chi2(3)`` :data:`NEES_PROBABILITY` quantile."""
    if "nees" not in rows:
        rows = rows.assign(nees=np.nan)
    chosen = rows[rows["method"].isin(methods) & rows["valid"].astype(bool)]
    chosen = chosen[chosen["nees"].notna()]
    threshold = chi2.ppf(NEES_PROBABILITY, 3)
    grouped = chosen.groupby([*KEYS, "phase"])["nees"]
    return pd.DataFrame(
        {
            "mean": grouped.mean(),
            "median": grouped.median(),
            "above": grouped.apply(lambda x: float(np.mean(x > threshold))),
        }
    )


def _consistency_lines(rows: pd.DataFrame, methods: Sequence[str]) -> list[str]:
    table = consistency_table(rows, methods)
    threshold = chi2.ppf(NEES_PROBABILITY, 3)
    lines = [
        "",
        "## Consistency",
        "",
        "Attitude NEES `e^T P^-1 e` of the valid rows against each method's own covariance "
        "(3 for a consistent estimator): mean, median and the share of rows above the "
        f"chi-square(3) {NEES_PROBABILITY} quantile ({threshold:.1f}), converging / settled. "
        "The EKF and RTS rows are never flagged invalid, so a diverged pass shows here.",
        "",
        "| SNR dB | L | method | mean | median | share above | converging share above |",
        "|---|---|---|---|---|---|---|",
    ]
    for (snr, snapshots, method), _ in table.groupby(level=KEYS, sort=True):
        settled = _entry(table, (snr, snapshots, method, "settled"))
        converging = _entry(table, (snr, snapshots, method, "converging"))
        lines.append(
            f"| {snr:g} | {snapshots} | {method} | {_f(settled['mean'], '.3g')} "
            f"| {_f(settled['median'], '.3g')} | {_f(settled['above'])} "
            f"| {_f(converging['above'])} |"
        )
    return lines


def _runtime_lines(rows: pd.DataFrame, methods: Sequence[str]) -> list[str]:
    lines = [
        "",
        "## Runtime",
        "",
        "Mean wall-clock time per pass (s), as each method's rows report it.",
        "",
        "| method | passes | mean runtime (s) |",
        "|---|---|---|",
    ]
    for method, r in runtime_table(rows, methods).iterrows():
        lines.append(f"| {method} | {r['count']:.0f} | {_f(r['mean'], '.3g')} |")
    return lines


def _convergence_lines(
    rows: pd.DataFrame, methods: Sequence[str], qs: Sequence[float], out_dir: Path
) -> list[str]:
    curves, snr, snapshots = convergence_trial(rows, methods)
    _figure(
        curves,
        qs,
        f"First trial, SNR {snr:g} dB, L = {snapshots} (seed 003 Figs. 6-7)",
        out_dir / "doa_convergence.png",
    )
    lines = [
        "",
        "## Convergence (seed 003 Figs. 6-7)",
        "",
        f"First trial at SNR {snr:g} dB, L = {snapshots}. Seed 003: Euler-angle errors within "
        f"{ATTITUDE_THRESHOLD_DEG} deg within 1500 s, rate errors {RATE_THRESHOLD_DEG_S} deg/s "
        "after about 1000 s.",
        "",
    ]
    for q in qs:
        if ekf_method(q) in curves:
            attitude_time, rate_time = convergence_times(curves[ekf_method(q)])
            lines.append(
                f"* EKF Q = {q:.0e}: Euler-angle errors within {ATTITUDE_THRESHOLD_DEG} deg "
                f"{_since(attitude_time)}, rate errors within {RATE_THRESHOLD_DEG_S} deg/s "
                f"{_since(rate_time)}."
            )
    return [*lines, "", "![convergence](doa_convergence.png)"]


def report(ctx: ReportContext) -> str:
    """Markdown: Tables 1-2 (ours beside seed 003), the smoother target, runtimes and
    the convergence figure (written to ``ctx.out_dir``)."""
    parameters = ctx.parameters
    qs = process_noises(parameters)
    methods = attitude_methods(ctx.rows, parameters)
    doa = doa_table(ctx.rows)
    attitude = attitude_table(ctx.rows, methods)
    settings = ctx.rows[SETTING].dropna().drop_duplicates()
    lines = [
        "## Seed 003 tables, the smoothers and the bounds",
        "",
        "DOA: RMSE over the accepted MUSIC estimates of all trials, the RMS Cramer-Rao bound "
        "at the true DOAs and the share of estimates MUSIC accepted; seed 003 in brackets.",
        "Attitude (seed 003 eq. 34): RMSE over the valid rows with "
        f"t >= {_f(parameters.get('settle_s'), '.0f')} s of all trials, every "
        f"{_f(parameters.get('row_step_s'), 'g')} s; yaw / roll / pitch are 3-2-1 Euler-angle "
        "differences, the total RMS is over the three body-axis errors (deg). Bound: the "
        "filter's or smoother's posterior Cramer-Rao bound (`pbound`) of its own model "
        "(for the EKF and RTS rows the dynamics with process noise Q per step, which the "
        "torque-free truth does not have, so errors below it are possible); for `wahba` the "
        "single-epoch CRB where two or more stations are accepted. CRB (Q = 0): the "
        "Cramer-Rao bound of the seed's problem itself (known deterministic dynamics, all "
        "DOAs up to the epoch for the EKF, of the pass for the RTS). Valid: share of settled "
        "rows with a solution; trials: trials with at least one.",
        f"`{BATCH_LS}` (batch least squares over the seed's dynamics, Q = 0; its bound is "
        "the CRB), `mekf` and `fg_batch` (gyro-aided) run only in the first "
        f"{_f(parameters.get('filter_trials'), '.0f')} trials of a setting.",
    ]
    lines += _seed_table(
        "Seed 003 Table 1",
        _table_settings(
            settings,
            "snapshots",
            parameters.get("table1_snapshots", SEED003_TABLE1_SNAPSHOTS),
            "snr_db",
            parameters.get("table1_snr_db"),
        ),
        doa,
        attitude,
        methods,
    )
    lines += _seed_table(
        "Seed 003 Table 2",
        _table_settings(
            settings,
            "snr_db",
            parameters.get("table2_snr_db", SEED003_TABLE2_SNR_DB),
            "snapshots",
            parameters.get("table2_snapshots"),
        ),
        doa,
        attitude,
        methods,
    )
    ordered = [(float(a), int(b)) for a, b in settings.sort_values(SETTING).to_numpy()]
    lines += _summary_lines(ordered, doa, attitude, qs)
    lines += _smoother_lines(ctx.rows, methods, qs)
    lines += _consistency_lines(ctx.rows, methods)
    lines += _runtime_lines(ctx.rows, methods)
    lines += _convergence_lines(ctx.rows, methods, qs, ctx.out_dir)
    return "\n".join(lines) + "\n"
