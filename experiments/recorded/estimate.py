"""``attopt estimate``: registered estimators on a recorded pass, with an experiment's outputs.

:func:`estimate` runs the estimators by registry name
(:func:`attopt.solvers.pipeline.run_estimators`) on the pass each needs:
snapshot estimators, and the pass estimators on rigid-body dynamics
(:attr:`PassEstimator.motion <attopt.solvers.estimator.PassEstimator.motion>`
``"dynamics"``: Yang et al. 2014's EKF, its RTS pass, the batch least
squares), on the pass's measurements relative to the attitude frame with the
dynamics and that frame's prior (:attr:`RecordedPass.pass_
<attopt.experiments.recorded.recorded_pass.RecordedPass.pass_>`); the
gyro-aided pass estimators (``motion`` ``"gyro"``) on the gyro-aided pass when
the recording has a gyro
(:attr:`~attopt.experiments.recorded.recorded_pass.RecordedPass.gyro_pass`,
with the ECI prior, their tracks turned back to the attitude frame,
:func:`attopt.experiments.metrics.in_orbit_frame`), else on ``pass_``.
Estimators on the same pass run together, so one starts from another's track
(``starts_from``: ``rts`` from ``mekf``, ``rts_yang2014`` from ``ekf_yang2014``).

:func:`write_outputs` writes what an experiment writes, from the same helpers:

* ``rows.parquet``: per method and epoch, ``method``, ``t_s``, the estimate
  ``q_est_{x,y,z,w}`` (scalar last, ``attitude_frame`` -> body) and its own
  ``sigma_{x,y,z}_deg``, ``valid``, ``reason`` and ``runtime_s``; with a truth
  table also ``q_true_{x,y,z,w}`` and :func:`attopt.experiments.metrics.error_columns`
  (``err_{x,y,z}_deg``, ``nees``, the Euler-angle differences);
* ``summary.csv``: per method, :func:`attopt.experiments.sweep.aggregate.summarise`'s
  statistics with a truth table, else the valid share and the median sigmas;
* ``report.md``: the pass, the estimators' table and, with a truth table, the
  integrity section (:func:`attopt.experiments.reporting.integrity.integrity_section`);
* one figure per method (:meth:`Track.plot <attopt.solvers.results.Track.plot>`):
  the error with its +/-3 sigma band, or without truth the estimate's 3-2-1
  Euler angles with theirs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import typer

from attopt.experiments.metrics import (
    attitude_columns,
    error_columns,
    in_orbit_frame,
    status_columns,
)
from attopt.experiments.recorded.recorded_pass import RecordedPass, load_pass
from attopt.experiments.reporting.figures import image_links, save_figure
from attopt.experiments.reporting.integrity import integrity_section
from attopt.experiments.reporting.statistics import AXES, error_summary
from attopt.experiments.reporting.tables import document, joined, made_by, markdown_table, section
from attopt.experiments.sweep.aggregate import summarise
from attopt.formulations.errors import AttoptError
from attopt.solvers.estimator import PassEstimator
from attopt.solvers.pipeline import Run, run_estimators
from attopt.solvers.registry import UnknownEstimatorError, estimator
from attopt.solvers.results import observable_sigma

ROWS = "rows.parquet"
SUMMARY = "summary.csv"
REPORT = "report.md"
USAGE_ERROR = 2
"""Exit status of a bad pass or method, as for the other commands' bad input."""


def estimate(recorded: RecordedPass, methods: Sequence[str]) -> dict[str, Run]:
    """Each method's :class:`~attopt.solvers.pipeline.Run` on ``recorded``, its track
    relative to the pass's attitude frame (module docstring).

    Raises:
        UnknownEstimatorError: a name the registry does not have.
        AttoptError: an estimator that cannot solve the pass (e.g. a filter on a pass
            without a gyro, or measurements it does not accept).

    Example::

        >>> import numpy as np
        >>> from attopt.experiments.recorded.estimate import estimate
        >>> from attopt.experiments.wahba_mag_sun.experiment import EXPERIMENT
        >>> from attopt.experiments.wahba_mag_sun.export import export
        >>> setting = {**EXPERIMENT.parameters, "duration_s": 30.0}
        >>> recorded = export(setting, np.random.SeedSequence(0))
        >>> runs = estimate(recorded, ["quest", "mekf"])
        >>> [(name, int(run.track.valid.sum())) for name, run in runs.items()]
        [('quest', 30), ('mekf', 30)]
    """
    chosen = {name: estimator(name) for name in methods}
    gyro_aided = {
        n: e for n, e in chosen.items() if isinstance(e, PassEstimator) and e.motion == "gyro"
    }
    on_pass = {n: e for n, e in chosen.items() if n not in gyro_aided}
    runs = run_estimators(recorded.pass_, on_pass) if on_pass else {}
    if gyro_aided:
        gyro = recorded.gyro_pass
        turned = gyro is not None and recorded.frames is not None
        for name, run in run_estimators(gyro or recorded.pass_, gyro_aided).items():
            track = in_orbit_frame(run.track, recorded.frames) if turned else run.track
            runs[name] = replace(run, track=track)
    return {name: runs[name] for name in methods}


def method_rows(name: str, run: Run, recorded: RecordedPass) -> pd.DataFrame:
    """The rows of one method (module docstring)."""
    track, truth = run.track, recorded.truth
    if truth is not None:
        metrics = error_columns(track, truth)
    else:
        sigma = np.degrees(observable_sigma(track.covariance))
        metrics = {f"sigma_{a}_deg": sigma[:, i] for i, a in enumerate(AXES)}
    return pd.DataFrame(
        {
            "method": name,
            "t_s": recorded.t,
            **attitude_columns(np.where(track.valid[:, None], track.quaternion, np.nan), truth),
            **metrics,
            **status_columns(track),
            "runtime_s": run.seconds,
        }
    )


def summary_table(rows: pd.DataFrame, truth: bool) -> pd.DataFrame:
    """Per method: :func:`~attopt.experiments.sweep.aggregate.summarise`'s statistics with
    a truth table, else ``n_rows``, ``n_valid``, ``valid_fraction`` and the median
    ``sigma_{x,y,z}_deg`` over the valid rows; ``runtime_s``."""
    groups = rows.groupby("method", sort=False)
    runtime = groups["runtime_s"].first()
    if truth:
        empty = pd.DataFrame(columns=["setting_index"])
        table = summarise(
            rows.assign(setting_index=0), empty, setting_columns=[], group_by=["method"]
        )
        table = table.drop(columns=["setting_index", "failed_trials"]).set_index("method")
        table = table.loc[runtime.index]
    else:
        valid = rows[rows["valid"]].groupby("method", sort=False)
        table = pd.DataFrame({"n_rows": groups.size(), "n_valid": groups["valid"].sum()})
        table["valid_fraction"] = table["n_valid"] / table["n_rows"]
        for a in AXES:
            table[f"sigma_{a}_median_deg"] = valid[f"sigma_{a}_deg"].median()
    return table.assign(runtime_s=runtime).reset_index()


def _estimators_section(
    rows: pd.DataFrame, summary: pd.DataFrame, truth: bool, command: str
) -> str:
    if truth:
        stats = pd.DataFrame(
            [error_summary(group) for _, group in rows.groupby("method", sort=False)]
        )
        table = summary[["method"]].assign(
            valid=stats["valid_fraction"].to_numpy(),
            **{"RMS roll / pitch / yaw (deg)": joined(stats, [f"rms_{a}" for a in AXES])},
            **{"total RMS (deg)": stats["total_rms"].to_numpy()},
            **{"mean NEES": stats["mean_nees"].to_numpy()},
            **{"inside 3 sigma": stats["inside_3_sigma"].to_numpy()},
        )
        caption = (
            "Per estimator over the pass's epochs: the valid share and, over the valid "
            "epochs, the body-axis RMS error against the truth table, its total, the mean "
            "NEES (3 when consistent) and the share within 3 sigma on every axis."
        )
    else:
        table = summary[["method", "valid_fraction"]].assign(
            **{
                "median sigma roll / pitch / yaw (deg)": joined(
                    summary, [f"sigma_{a}_median_deg" for a in AXES], ".4g"
                )
            }
        )
        caption = (
            "Per estimator: the valid share of the epochs and, over the valid ones, the "
            "median of its own standard deviation per body axis.  The pass has no truth "
            "table: no errors, NEES or integrity."
        )
    table = table.assign(**{"runtime (s)": summary["runtime_s"].to_numpy()})
    formats = {"valid": ".3f", "valid_fraction": ".3f", "runtime (s)": ".3g"}
    return section("Estimators", caption + made_by(command), markdown_table(table, formats))


def report(
    recorded: RecordedPass,
    rows: pd.DataFrame,
    summary: pd.DataFrame,
    figures: list[str],
    command: str = "",
) -> str:
    """``report.md``: the pass, the estimators' table, the integrity section (with a truth
    table) and the figures."""
    metadata, truth = recorded.metadata, recorded.truth is not None
    tables = ", ".join(f"{name} ({len(frame)} rows)" for name, frame in recorded.tables.items())
    start = f" from {metadata.start_utc} UTC" if metadata.start_utc else ""
    facts = (
        f"{metadata.description or 'A recorded pass'}: {len(recorded.t)} epochs, "
        f"t = {recorded.t[0]:g}-{recorded.t[-1]:g} s{start}; attitude relative to the "
        f"{metadata.attitude_frame} frame; tables {tables}."
    )
    parts = [
        "# Estimates of a recorded pass\n\n" + facts + "\n",
        _estimators_section(rows, summary, truth, command),
        integrity_section(rows, ["method"], command) if truth else "",
        section("Figures", image_links(figures)),
    ]
    return document(parts)


def write_outputs(
    recorded: RecordedPass, runs: dict[str, Run], out: Path, command: str = ""
) -> pd.DataFrame:
    """Write rows, summary, report and figures of ``runs`` to ``out`` (module docstring);
    returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = pd.concat(
        [method_rows(name, run, recorded) for name, run in runs.items()], ignore_index=True
    )
    rows.to_parquet(out / ROWS, index=False)
    summary = summary_table(rows, recorded.truth is not None)
    summary.to_csv(out / SUMMARY, index=False)
    kind = "errors" if recorded.truth is not None else "estimates"
    figures = [
        save_figure(
            replace(run.track, t=recorded.t).plot(recorded.truth), out, f"{kind}_{name}.png"
        )
        for name, run in runs.items()
    ]
    (out / REPORT).write_text(report(recorded, rows, summary, figures, command))
    return summary


def main(pass_dir: Path, methods: str, out: Path | None) -> int:
    """``attopt estimate PASS_DIR --methods a,b --out DIR``: load, estimate, write, print
    the summary; a bad pass or method is one line on stderr and exit status 2.

    Example::

        >>> import tempfile
        >>> from pathlib import Path
        >>> from attopt.experiments.recorded.estimate import main
        >>> main(Path(tempfile.mkdtemp()) / "absent", "quest", None)
        2
    """
    names = [name.strip() for name in methods.split(",") if name.strip()]
    out = out or Path("results") / f"estimate-{Path(pass_dir).name}"
    command = f"attopt estimate {pass_dir} --methods {','.join(names)} --out {out}"
    try:
        if not names:
            raise UnknownEstimatorError("--methods names no estimator (see `attopt estimators`)")
        recorded = load_pass(pass_dir)
        runs = estimate(recorded, names)
    except (AttoptError, UnknownEstimatorError) as error:
        typer.echo(f"error: {' '.join(str(error).split())}", err=True)
        return USAGE_ERROR
    summary = write_outputs(recorded, runs, out, command)
    typer.echo(f"Results in {out}/ ({ROWS}, {SUMMARY}, {REPORT}, figures)\n")
    typer.echo(summary.to_string(index=False, float_format="{:.4g}".format))
    return 0
