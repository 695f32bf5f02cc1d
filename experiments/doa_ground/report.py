"""Report of ``doa-ground``: Yang et al. 2014 Tables 1 and 2 beside ours, a summary line
per setting, the smoothers against the EKF on the same trials, consistency by phase,
integrity, the configured stations, runtimes and the convergence (Figs. 6-7).

Pooling:

* DOA RMSEs pool every accepted MUSIC estimate of every trial (the ``music``
  row of a trial holds its counts and mean squared errors, weighted by the
  accepted count; the CRB by the count of estimates), over all stations or per
  configured station (its ``..._station<k>`` columns).
* Attitude RMSEs follow Yang et al. 2014 eq. 34: one root mean square over
  all ``settled`` rows with an estimate of all trials of a setting: the valid
  rows and those the start check alone flags (the paper's EKF's and RTS's
  estimates, not confirmed by it: :mod:`attopt.solvers.start_hypotheses`; the
  ``valid`` share counts only the valid rows).  Yaw, roll and pitch
  are the 3-2-1 Euler-angle differences; the total is ``sqrt(mean(err_x^2 +
  err_y^2 + err_z^2))`` of the body-axis errors, and the bound's total the
  same of ``pbound_*`` (posterior bound of a pass) or ``bound_*`` (single-epoch
  CRB), and ``crb_*`` (the EKF's and RTS's bound with ``Q = 0``) likewise.
* The smoother table pools, per setting, only the trials in which the
  :data:`~attopt.experiments.doa_ground.methods.SUBSET_METHODS` ran (all
  trials if none ran in that setting), the same trials for every column.
* Runtimes: mean over passes (one ``runtime_s`` per trial and method).

What the bounds are and why ours differ from the paper's: ``docs/doa.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from attopt.experiments.doa_ground.methods import (
    BATCH_LS,
    SMOOTHER,
    SUBSET_METHODS,
    attitude_methods,
    ekf_method,
    process_noises,
    rts_method,
)
from attopt.experiments.experiment import ReportContext
from attopt.experiments.reporting.figures import error_figure, image_links, save_figure
from attopt.experiments.reporting.integrity import integrity_section
from attopt.experiments.reporting.paper_values import paper_label, paper_table, paper_values
from attopt.experiments.reporting.statistics import (
    AXES,
    integrity,
    nees_threshold,
    squared_norm,
)
from attopt.experiments.reporting.tables import (
    cell,
    document,
    joined,
    made_by,
    markdown_table,
    section,
    with_paper,
)
from attopt.solvers.start_hypotheses import flagged_by_start_check

PACKAGE = "attopt.experiments.doa_ground"
EULER = ("yaw", "roll", "pitch")
SETTING = ["snr_db", "snapshots"]
SETTING_NAMES = {"snr_db": "SNR dB", "snapshots": "L"}
SETTING_FORMATS = {"SNR dB": "g"}
KEYS = [*SETTING, "method"]
TABLE1_SNAPSHOTS = 100
TABLE2_SNR_DB = 0.0


def doa_table(rows: pd.DataFrame, station: int | None = None) -> pd.DataFrame:
    """Per ``(snr_db, snapshots)``: pooled DOA RMSE, RMS CRB at the truth and acceptance, of
    all stations or of ``station`` (1-based index of the configured stations: the music
    rows' ``..._station<k>`` columns)."""
    tag = "" if station is None else f"_station{station}"
    music = rows[rows["method"] == "music"].copy()
    weight = music[f"doa_accepted{tag}"]
    count = music[f"doa_count{tag}"]
    music["theta_sq"] = music[f"doa_theta_mse{tag}_deg2"].fillna(0.0) * weight
    music["phi_sq"] = music[f"doa_phi_mse{tag}_deg2"].fillna(0.0) * weight
    music["crb_theta_sq"] = music[f"doa_crb_theta{tag}_deg2"].fillna(0.0) * count
    music["crb_phi_sq"] = music[f"doa_crb_phi{tag}_deg2"].fillna(0.0) * count
    music["accepted_n"], music["count_n"] = weight, count
    sums = music.groupby(SETTING)[
        ["theta_sq", "phi_sq", "crb_theta_sq", "crb_phi_sq", "accepted_n", "count_n"]
    ].sum()
    return pd.DataFrame(
        {
            "theta_rmse_deg": np.sqrt(sums["theta_sq"] / sums["accepted_n"]),
            "phi_rmse_deg": np.sqrt(sums["phi_sq"] / sums["accepted_n"]),
            "crb_theta_deg": np.sqrt(sums["crb_theta_sq"] / sums["count_n"]),
            "crb_phi_deg": np.sqrt(sums["crb_phi_sq"] / sums["count_n"]),
            "accepted": sums["accepted_n"] / sums["count_n"],
        }
    )


def attitude_table(rows: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per ``(snr_db, snapshots, method)``: settled Euler and total RMSEs (eq. 34 pooling,
    rows with an estimate: module docstring), the bound's total RMS, RMS / bound, valid
    share and contributing trials."""
    settled = rows[(rows["phase"] == "settled") & rows["method"].isin(methods)]
    valid = settled["valid"].astype(bool)
    good = settled[valid | flagged_by_start_check(settled["reason"].fillna(""))]
    squares = pd.DataFrame(
        {
            **{f"{n}_rmse_deg": good[f"euler_{n}_err_deg"] ** 2 for n in EULER},
            "total_rmse_deg": squared_norm(good, "err"),
            "bound_total_deg": squared_norm(good, "pbound").fillna(squared_norm(good, "bound")),
            "crb_total_deg": squared_norm(good, "crb"),
        }
    )
    share = valid.groupby([settled[k] for k in KEYS]).mean()
    table = np.sqrt(squares.groupby([good[k] for k in KEYS]).mean()).reindex(share.index)
    table["ratio"] = table["total_rmse_deg"] / table["bound_total_deg"]
    table["valid"] = share
    table["trials"] = good.groupby(KEYS)["trial_index"].nunique().reindex(share.index).fillna(0)
    return table


def shared_trials(rows: pd.DataFrame) -> pd.DataFrame:
    """The rows of the trials in which the subset methods ran, per setting (every trial of a
    setting in which none ran)."""
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


def consistency_table(rows: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per ``(snr_db, snapshots, method, phase)``: mean and median attitude NEES of the valid
    rows and their share above the chi-square(3) integrity quantile."""
    chosen = rows[rows["method"].isin(methods)]
    table = integrity(chosen, [*KEYS, "phase"])
    valid = chosen[chosen["valid"].astype(bool)]
    median = valid.groupby([*KEYS, "phase"])["nees"].median()
    return pd.DataFrame(
        {"mean": table["mean_nees"], "median": median, "above": table["share_beyond"]}
    ).dropna(how="all")


def convergence_times(
    curve: pd.DataFrame, attitude_deg: float, rate_deg_s: float
) -> tuple[float, float]:
    """First times after which every Euler error stays within ``attitude_deg`` and every
    rate error within ``rate_deg_s`` (NaN if not at the end of the pass)."""
    attitude = curve[[f"euler_{n}_err_deg" for n in EULER]].abs().max(axis=1) > attitude_deg
    rate = curve[[f"rate_err_{a}_deg_s" for a in AXES]].abs().max(axis=1) > rate_deg_s
    return _settling_time(curve["t_s"], attitude), _settling_time(curve["t_s"], rate)


def _settling_time(t: pd.Series, outside: pd.Series) -> float:
    if outside.iloc[-1]:
        return float("nan")
    last = np.flatnonzero(outside.to_numpy())
    return float(t.iloc[last[-1] + 1]) if last.size else float(t.iloc[0])


def nearest_setting(settings: pd.DataFrame, snr_db: float, snapshots: int) -> tuple[float, int]:
    """The ``(snr_db, snapshots)`` among ``settings`` nearest the given ones (SNR in dB plus
    decades of ``L``)."""
    settings = settings[SETTING].drop_duplicates()
    distance = (settings["snr_db"] - snr_db).abs() + np.abs(
        np.log10(settings["snapshots"] / snapshots)
    )
    snr, count = settings.iloc[int(np.argmin(distance.to_numpy()))]
    return float(snr), int(count)


def convergence_trial(
    rows: pd.DataFrame, methods: Sequence[str], snr_db: float, snapshots: int
) -> tuple[dict[str, pd.DataFrame], float, int]:
    """Rows (sorted by ``t_s``) per method of the first trial of the setting nearest
    ``snr_db`` and ``snapshots``, with that setting's SNR and ``L``."""
    attitude = rows[rows["method"].isin(methods)]
    snr, count = nearest_setting(attitude, snr_db, snapshots)
    chosen = attitude[(attitude["snr_db"] == snr) & (attitude["snapshots"] == count)]
    first = chosen[chosen["trial_index"] == chosen["trial_index"].min()].sort_values("t_s")
    return dict(tuple(first.groupby("method"))), snr, count


def station_table(
    rows: pd.DataFrame, parameters: Mapping[str, Any], snr_db: float, snapshots: int
) -> pd.DataFrame:
    """Per configured station at the setting nearest ``snr_db``, ``snapshots``: its
    position, visible time per pass, DOAs accepted, and DOA RMSE and RMS CRB (deg)."""
    music = rows[rows["method"] == "music"]
    snr, count = nearest_setting(music, snr_db, snapshots)
    chosen = music[(music["snr_db"] == snr) & (music["snapshots"] == count)]
    lines = []
    for k, station in enumerate(parameters["stations"], start=1):
        doa = doa_table(chosen, k).iloc[0]
        lines.append(
            {
                "station": station["name"],
                "latitude (deg)": station["latitude_deg"],
                "longitude (deg)": station["longitude_deg"],
                "height (m)": station["height_m"],
                "visible per pass (s)": chosen[f"doa_count_station{k}"].mean()
                * parameters["step_s"],
                **doa.to_dict(),
            }
        )
    return pd.DataFrame(lines)


def _entry(table: pd.DataFrame, key: tuple[Any, ...]) -> pd.Series:
    """Row ``key`` of ``table``, or NaN in every column."""
    return table.loc[key] if key in table.index else pd.Series(np.nan, index=table.columns)


def _table_settings(
    settings: pd.DataFrame, fixed: str, value: float, swept: str, values: Sequence[float] | None
) -> list[tuple[float, int]]:
    """Settings with ``fixed == value`` (and ``swept`` in ``values`` if given), by ``swept``."""
    chosen = settings[settings[fixed] == value]
    if values is not None:
        chosen = chosen[chosen[swept].isin([float(v) for v in values])]
    return [(float(s), int(n)) for s, n in chosen.sort_values(swept)[SETTING].to_numpy()]


def _paper(name: str) -> pd.DataFrame:
    table = paper_table(PACKAGE, name)
    return table.astype({"snr_db": float, "snapshots": int}).set_index(SETTING)


def _papers() -> pd.DataFrame:
    """Tables 1 and 2 together, one row per setting."""
    both = pd.concat([_paper("table1"), _paper("table2")])
    return both[~both.index.duplicated()]


def paper_table_section(
    name: str,
    settings: Sequence[tuple[float, int]],
    doa: pd.DataFrame,
    attitude: pd.DataFrame,
    methods: Sequence[str],
    command: str,
) -> str:
    """One of the paper's tables: our DOA and attitude RMSEs beside it."""
    label = paper_label(PACKAGE, name)
    paper = _paper(name)
    index = pd.MultiIndex.from_tuples(settings, names=SETTING)
    doa_rows = doa.reindex(index).set_axis(
        ["theta RMSE", "phi RMSE", "CRB theta", "CRB phi", "accepted"], axis=1
    )
    doa_rows = with_paper(
        doa_rows.reset_index(), paper[["theta", "phi"]].reset_index(), SETTING, label
    )
    keys = pd.MultiIndex.from_tuples([(*k, m) for k in settings for m in methods], names=KEYS)
    ours = attitude.reindex(keys).reset_index()
    beside = joined(paper.reindex(pd.MultiIndex.from_frame(ours[SETTING])), EULER).to_numpy()
    lines = ours[KEYS].assign(
        **{n: ours[f"{n}_rmse_deg"] for n in EULER},
        **{
            f"EKF yaw / roll / pitch ({label})": np.where(
                ours["method"].str.startswith("ekf_"), beside, ""
            )
        },
        **{
            "total RMS": ours["total_rmse_deg"],
            "bound RMS": ours["bound_total_deg"],
            "RMS / bound": ours["ratio"],
            "CRB (Q = 0)": ours["crb_total_deg"],
            "valid": ours["valid"],
            "trials": ours["trials"],
        },
    )
    caption = (
        "DOA: RMSE over the accepted MUSIC estimates of all trials, RMS Cramer-Rao bound at the "
        "true DOAs and the share accepted. Attitude: eq. 34 RMSE over the settled rows of all "
        "trials with an estimate, valid or flagged by the EKF's start check alone (3-2-1 "
        "Euler-angle differences; total over the body axes), the RMS of each "
        "row's bound (posterior bound of the method's own model, single-epoch CRB for wahba), "
        "the Cramer-Rao bound of the paper's problem (Q = 0), the valid share and the trials "
        "with a solution (deg)." + made_by(command)
    )
    formats = {"RMS / bound": ".2f", "CRB (Q = 0)": ".4f", "trials": ".0f"}
    return section(
        f"{label} beside ours",
        caption,
        markdown_table(doa_rows.rename(columns=SETTING_NAMES), SETTING_FORMATS, spec=".3f"),
        markdown_table(lines.rename(columns=SETTING_NAMES), SETTING_FORMATS | formats, spec=".3f"),
    )


def summary_section(
    settings: Sequence[tuple[float, int]],
    doa: pd.DataFrame,
    attitude: pd.DataFrame,
    qs: Sequence[float],
    command: str,
) -> str:
    """One line per setting: DOA against the CRB, the EKFs' Euler RMSEs at the paper's and
    the lowest ``Q`` (the paper's beside the lowest), the lowest-``Q`` RTS, the batch least
    squares and the whole pass's ``Q = 0`` CRB (totals)."""
    paper = _papers()
    label = paper_values(PACKAGE)["paper"]
    first, low = qs[0], min(qs)
    lines = []
    for key in settings:
        seed = paper.loc[key] if key in paper.index else pd.Series(np.nan, index=paper.columns)
        d = _entry(doa, key)
        line = {"SNR dB": key[0], "L": key[1]}
        for angle in ("theta", "phi"):
            line[f"{angle} / CRB ({label})"] = (
                f"{cell(d[f'{angle}_rmse_deg'], '.3f')} / {cell(d[f'crb_{angle}_deg'], '.3f')} "
                f"({cell(seed[angle], '.3f')})"
            )
        line["accepted"] = d["accepted"]
        for q in dict.fromkeys([first, low]):
            euler = _entry(attitude, (*key, ekf_method(q)))
            text = ", ".join(cell(euler[f"{n}_rmse_deg"], ".3f") for n in EULER)
            if q == low and low != first:
                text += f" ({', '.join(cell(seed[n], '.3f') for n in EULER)})"
            suffix = f" ({label})" if q == low and low != first else ""
            line[f"EKF Q = {q:.0e}: yaw, roll, pitch{suffix}"] = text
        line[f"RTS Q = {low:.0e}"] = _entry(attitude, (*key, rts_method(low)))["total_rmse_deg"]
        line[BATCH_LS] = cell(_entry(attitude, (*key, BATCH_LS))["total_rmse_deg"], ".4f")
        line["CRB (Q = 0)"] = cell(
            _entry(attitude, (*key, rts_method(low)))["crb_total_deg"], ".4f"
        )
        lines.append(line)
    caption = (
        "DOA RMSE / RMS CRB (deg) and the share accepted; settled attitude RMSEs (deg): the "
        "EKFs' yaw, roll, pitch (the paper's in brackets), the total RMS of the RTS pass and "
        f"of `{BATCH_LS}` (in the trials it ran in), and the total of the whole pass's CRB "
        "(Q = 0, the RTS rows' `crb_*`)." + made_by(command)
    )
    return section(
        "Summary", caption, markdown_table(pd.DataFrame(lines), SETTING_FORMATS, spec=".3f")
    )


def smoother_section(
    rows: pd.DataFrame, methods: Sequence[str], qs: Sequence[float], command: str
) -> str:
    """Per setting, on the trials the subset methods ran in: total settled RMS of every EKF,
    RTS, the batch least squares, the gyro-aided rows, and the smoothers' ratios to each EKF."""
    shared = shared_trials(rows)
    table = attitude_table(shared, methods)
    trials = shared.groupby(SETTING)["trial_index"].nunique()
    ratios = [("RTS", rts_method), (BATCH_LS, lambda _: BATCH_LS), (SMOOTHER, lambda _: SMOOTHER)]
    lines = []
    for key, count in trials.items():

        def total(method: str, column: str = "total_rmse_deg", key=key) -> float:
            return _entry(table, (*key, method))[column]

        line = {"SNR dB": key[0], "L": key[1], "trials": count}
        line |= {f"EKF Q = {q:.0e}": total(ekf_method(q)) for q in qs}
        line |= {f"RTS Q = {q:.0e}": total(rts_method(q)) for q in qs}
        if BATCH_LS in methods:
            line[f"{BATCH_LS} (CRB)"] = (
                f"{cell(total(BATCH_LS), '.4f')} ({cell(total(BATCH_LS, 'crb_total_deg'), '.4f')})"
            )
        for method in (m for m in methods if m in SUBSET_METHODS and m != BATCH_LS):
            line[method] = cell(total(method), ".3f")
            if method == SMOOTHER:
                bound = cell(total(method, "bound_total_deg"), ".3f")
                line[f"{method} (pass bound)"] = f"{line.pop(method)} ({bound})"
        for label, method_of in ratios:
            for q in qs:
                if method_of(q) in methods:
                    line[f"{label} / EKF {q:.0e}"] = total(method_of(q)) / total(ekf_method(q))
        lines.append(line)
    caption = (
        "Total settled RMS (deg) per setting over the trials in which "
        f"`{'`, `'.join(SUBSET_METHODS)}` ran (all trials where none did), the same trials "
        "for every column; RTS over the EKF of the same Q; "
        f"`{BATCH_LS}` beside its Cramer-Rao bound (Q = 0), `{SMOOTHER}` beside the posterior "
        "bound of its pass with the gyro; ratios to each EKF." + made_by(command)
    )
    formats = {c: ".2f" for c in lines[0] if " / EKF " in c} if lines else {}
    return section(
        "Smoothers against the EKF on the same data",
        caption,
        markdown_table(pd.DataFrame(lines), SETTING_FORMATS | formats, spec=".3f"),
    )


def consistency_section(rows: pd.DataFrame, methods: Sequence[str], command: str) -> str:
    """Mean and median NEES once settled and the share beyond the quantile in both phases."""
    table = consistency_table(rows, methods)
    lines = []
    for (snr, snapshots, method), _ in table.groupby(level=KEYS, sort=True):
        settled = _entry(table, (snr, snapshots, method, "settled"))
        converging = _entry(table, (snr, snapshots, method, "converging"))
        lines.append(
            {
                "SNR dB": snr,
                "L": snapshots,
                "method": method,
                "mean": settled["mean"],
                "median": settled["median"],
                "share beyond": settled["above"],
                "converging share beyond": converging["above"],
            }
        )
    caption = (
        "Attitude NEES of the valid settled rows against each method's own covariance (3 when "
        "consistent): mean, median and the share beyond the chi-square(3) 0.9999 quantile "
        f"({nees_threshold():.1f}), and that share while converging. The EKF and RTS rows "
        "count where their start check confirms them (docs/doa.md)." + made_by(command)
    )
    formats = SETTING_FORMATS | {"mean": ".3g", "median": ".3g"}
    return section("Consistency", caption, markdown_table(pd.DataFrame(lines), formats, spec=".3f"))


def station_section(ctx: ReportContext) -> str:
    """One line per configured station at the setting nearest the paper's first simulation
    (nothing without stations in the parameters or DOA rows)."""
    stated = paper_values(PACKAGE)["convergence"]
    music = ctx.rows[ctx.rows["method"] == "music"]
    if music.empty or not ctx.parameters.get("stations"):
        return ""
    snr, count = nearest_setting(music, stated["snr_db"], stated["snapshots"])
    table = station_table(ctx.rows, ctx.parameters, snr, count)
    lines = table.assign(
        **{
            "theta RMSE / CRB": [
                f"{cell(a, '.3f')} / {cell(b, '.3f')}"
                for a, b in zip(table["theta_rmse_deg"], table["crb_theta_deg"], strict=True)
            ],
            "phi RMSE / CRB": [
                f"{cell(a, '.3f')} / {cell(b, '.3f')}"
                for a, b in zip(table["phi_rmse_deg"], table["crb_phi_deg"], strict=True)
            ],
        }
    ).drop(columns=["theta_rmse_deg", "phi_rmse_deg", "crb_theta_deg", "crb_phi_deg"])
    caption = (
        f"The configured stations at SNR {snr:g} dB, L = {count}: geodetic position, time "
        "above the minimum elevation per pass, the share of MUSIC estimates accepted, and "
        "the DOA RMSE over the accepted estimates of all trials beside the RMS Cramer-Rao "
        "bound at the true DOAs (deg; - where the station is never visible)." + made_by(ctx.command)
    )
    formats = {"visible per pass (s)": ".0f", "height (m)": ".0f"}
    return section(
        "Stations", caption, markdown_table(lines, SETTING_FORMATS | formats, spec=".3f")
    )


def runtime_section(rows: pd.DataFrame, methods: Sequence[str], command: str) -> str:
    """Mean pass time per method."""
    table = runtime_table(rows, methods).reset_index()
    table.columns = ["method", "passes", "mean runtime (s)"]
    caption = "Mean wall-clock time per pass (s), as each method's rows report it." + made_by(
        command
    )
    return section(
        "Runtime", caption, markdown_table(table, {"mean runtime (s)": ".3g", "passes": ".0f"})
    )


def convergence_section(ctx: ReportContext, methods: Sequence[str], qs: Sequence[float]) -> str:
    """Convergence times of each EKF and the first trial's errors (Figs. 6-7)."""
    stated = paper_values(PACKAGE)["convergence"]
    label = paper_label(PACKAGE, "convergence")
    curves, snr, snapshots = convergence_trial(
        ctx.rows, methods, stated["snr_db"], stated["snapshots"]
    )
    attitude_column = f"Euler errors within {stated['attitude_deg']:g} deg from t (s)"
    rate_column = f"rate errors within {stated['rate_deg_s']:g} deg/s from t (s)"
    lines = [
        {
            "row": label,
            attitude_column: f"within {stated['attitude_within_s']:g}",
            rate_column: f"about {stated['rate_within_s']:g}",
        }
    ]
    for q in qs:
        if ekf_method(q) in curves:
            attitude, rate = convergence_times(
                curves[ekf_method(q)], stated["attitude_deg"], stated["rate_deg_s"]
            )
            lines.append({"row": f"EKF Q = {q:.0e}", attitude_column: attitude, rate_column: rate})
    drawn = [ekf_method(qs[0]), ekf_method(min(qs)), BATCH_LS]
    frames = {m: curves[m] for m in dict.fromkeys(drawn) if m in curves}
    figure = error_figure(
        frames, f"Body-axis error, first trial at SNR {snr:g} dB, L = {snapshots}", time="t_s"
    )
    for axis in figure.axes:
        axis.set_yscale("symlog", linthresh=0.1)
    name = save_figure(figure, ctx.out_dir, "doa_convergence.png")
    caption = (
        f"First trial at SNR {snr:g} dB, L = {snapshots}: when the EKF's 3-2-1 Euler-angle and "
        "rate errors last enter their thresholds (not at the end of the pass: -); the figure "
        "draws the body-axis errors with +/-3 sigma of their own covariance (symmetric log "
        "scale)." + made_by(ctx.command)
    )
    return section(
        f"Convergence ({label})",
        caption,
        markdown_table(pd.DataFrame(lines), spec=".0f"),
        image_links([name]),
    )


def report(ctx: ReportContext) -> str:
    """Markdown: Tables 1-2 beside ours, the summary, the smoothers, consistency, integrity,
    runtimes and convergence (the figure written to ``ctx.out_dir``)."""
    parameters: Mapping[str, Any] = ctx.parameters
    qs = process_noises(parameters)
    methods = attitude_methods(ctx.rows, parameters)
    doa = doa_table(ctx.rows)
    attitude = attitude_table(ctx.rows, methods)
    settings = ctx.rows[SETTING].dropna().drop_duplicates()
    table1 = _table_settings(
        settings,
        "snapshots",
        parameters.get("table1_snapshots", TABLE1_SNAPSHOTS),
        "snr_db",
        parameters.get("table1_snr_db"),
    )
    table2 = _table_settings(
        settings,
        "snr_db",
        parameters.get("table2_snr_db", TABLE2_SNR_DB),
        "snapshots",
        parameters.get("table2_snapshots"),
    )
    ordered = [(float(a), int(b)) for a, b in settings.sort_values(SETTING).to_numpy()]
    attitude_rows = ctx.rows[ctx.rows["method"].isin(methods)]
    return document(
        [
            paper_table_section("table1", table1, doa, attitude, methods, ctx.command),
            paper_table_section("table2", table2, doa, attitude, methods, ctx.command),
            summary_section(ordered, doa, attitude, qs, ctx.command),
            smoother_section(ctx.rows, methods, qs, ctx.command),
            consistency_section(ctx.rows, methods, ctx.command),
            integrity_section(attitude_rows, KEYS, ctx.command),
            station_section(ctx),
            runtime_section(ctx.rows, methods, ctx.command),
            convergence_section(ctx, methods, qs),
        ]
    )
