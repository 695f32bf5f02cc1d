"""The filter section of the adsb-snr report on synthetic rows (no sweep needed)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from attopt.experiments.adsb_snr.filter_report import (
    BURN_IN_S,
    burn_in,
    filter_report,
    nees_interval,
    run_averaged_nees,
)
from attopt.experiments.experiment import ReportContext

FILTERS = ["mekf_paper", "mekf_snr", "usque_snr", "rts_snr"]
GYROS = ["seed000", "mems"]
N_EPOCHS = 700
AXES = ("x", "y", "z")


def _frame(method: str, gyro: str, trial: int, error: np.ndarray, **extra) -> pd.DataFrame:
    """Rows of one method and trial with per-epoch body errors ``error`` (N, 3), deg."""
    t = np.arange(N_EPOCHS, dtype=float)
    frame = {
        "setting_index": 0,
        "trial_index": trial,
        "method": method,
        "gyro": gyro,
        "t": t,
        "valid": True,
        "reason": "",
        "runtime_s": extra.pop("runtime_s", 1.0),
    }
    for i, axis in enumerate(AXES):
        frame[f"err_{axis}_deg"] = error[:, i]
        frame[f"sigma_{axis}_deg"] = extra.get("sigma", 1.0)
    for i, name in enumerate(("roll", "pitch", "yaw")):
        frame[f"euler_{name}_err_deg"] = error[:, i]
    frame["nees"] = extra.pop("nees", 3.0)
    if gyro != "none":
        for axis in AXES:
            frame[f"bias_err_{axis}_deg_h"] = 1.0
            frame[f"bias_sigma_{axis}_deg_h"] = 2.0
        frame |= {"nees_full": 6.0, "n_used": 100.0, "n_gated": 1.0, "n_unpredictable": 0.0}
    frame |= {k: v for k, v in extra.items() if k != "sigma"}
    return pd.DataFrame(frame)


def _rows(
    filters=FILTERS,
    gyros=GYROS,
    trials: int = 2,
    snr_scale: dict | None = None,
    runtime: dict | None = None,
    nees: float = 3.0,
    **extra,
) -> pd.DataFrame:
    """Paper-filter errors of 1 deg on every axis after the burn-in (10 deg before);
    ``mekf_snr`` errors are ``snr_scale[gyro]`` times those."""
    snr_scale = snr_scale or {g: 0.4 for g in gyros}
    runtime = runtime or {}
    rng = np.random.default_rng(0)
    frames = []
    for trial in range(trials):
        signs = rng.choice([-1.0, 1.0], size=(N_EPOCHS, 3))
        base = signs * np.where(np.arange(N_EPOCHS) < BURN_IN_S, 10.0, 1.0)[:, None]
        frames.append(_frame("nlse", "none", trial, 1.5 * base, runtime_s=4.0))
        for gyro in gyros:
            for method in filters:
                scale = {"mekf_paper": 1.0, "mekf_snr": snr_scale[gyro]}.get(method, 0.3)
                frames.append(
                    _frame(
                        method,
                        gyro,
                        trial,
                        scale * base,
                        runtime_s=runtime.get(method, 2.0),
                        nees=nees,
                        **extra,
                    )
                )
    return pd.concat(frames, ignore_index=True)


def _context(rows: pd.DataFrame, tmp_path: Path, **parameters) -> ReportContext:
    base = {
        "duration_s": float(N_EPOCHS),
        "step_s": 1.0,
        "filters": FILTERS,
        "gyros": GYROS,
        "initial_sigma_deg": 10.0,
        "paper_sigma_deg": 1.0,
        "filter_snr_model": "truncated",
    }
    return ReportContext({**base, **parameters}, rows, pd.DataFrame(), tmp_path)


def _line(lines: list[str], start: str) -> str:
    return next(line for line in lines if line.startswith(start))


def test_no_filter_rows_gives_no_section(tmp_path):
    rows = _rows(filters=[])
    assert filter_report(_context(rows, tmp_path)) == []
    assert filter_report(_context(rows.drop(columns="gyro"), tmp_path)) == []
    assert not list(tmp_path.iterdir())


def test_section_tables_targets_and_figures(tmp_path):
    rows = _rows(snr_scale={"seed000": 0.4, "mems": 0.6})
    lines = filter_report(_context(rows, tmp_path))
    text = "\n".join(lines)
    assert lines[0] == "## Gyro-aided filters (issue 5)"
    assert "0.05 deg/s^(1/2)" in text and "0.05 deg/s^(3/2)" in text  # seed000's reading
    assert "sigma_v = 0.05 deg/s, sigma_u = 0.05 deg/s" in text  # the seed as printed
    # Table 2's MEKF row and ours, after the burn-in: 1 deg RMS on every axis.
    assert _line(lines, "| MEKF (seed 000 Table 2) |").split("|")[5].strip() == "0.28 / 0.15 / 0.24"
    settled = _line(lines, f"| mekf_paper, gyro seed000 | t >= {BURN_IN_S:g} s | Euler |")
    assert settled.split("|")[5].strip() == "1.00 / 1.00 / 1.00"
    # The comparison table: RMS ratio over the settled epochs, gated / unpredictable / used.
    row = _line(lines, "| seed000 | mekf_snr |").split("|")
    assert row[3].strip() == "0.400 / 0.400 / 0.400"
    assert row[4].strip() == "0.400"
    assert row[10].strip() == f"{2 * N_EPOCHS:,} / 0 / {100 * 2 * N_EPOCHS:,}"
    # Targets.
    accuracy = _line(lines, "- **(a) Accuracy**")
    assert "gyro seed000:" in accuracy and "ratio 0.400: **met**" in accuracy
    assert "ratio 0.600: **MISSED**" in accuracy
    assert f"**Not assessed**: the pass is {N_EPOCHS} s" in _line(lines, "- **(b) Runtime**")
    lo, hi = nees_interval(2)
    nees = _line(lines, "- **(c) NEES consistency**")
    assert f"[{lo:.3f}, {hi:.3f}]" in nees
    assert nees.count("inside: **met**") == 4 and "**MISSED**" not in nees
    assert "python -m attopt.experiments.benchmarks.filters" in text
    for gyro in GYROS:
        for name in (f"filter_errors_{gyro}.png", f"gyro_bias_{gyro}.png"):
            assert (tmp_path / name).stat().st_size > 10_000
            assert f"![{name}]({name})" in lines
    assert "not the bias estimate" in text


def test_runtime_and_nees_verdicts_on_the_hour(tmp_path):
    rows = _rows(runtime={"usque_snr": 12.0}, nees=20.0)
    lines = filter_report(_context(rows, tmp_path, duration_s=3600.0))
    runtime = _line(lines, "- **(b) Runtime**")
    assert "usque_snr 12.00 s" in runtime and "Target **MISSED** by usque_snr" in runtime
    nees = _line(lines, "- **(c) NEES consistency**")
    assert nees.count("outside: **MISSED**") == 4 and "**met**" not in nees


def test_burn_in_is_at_most_half_the_pass(tmp_path):
    rows = _rows()
    assert burn_in(_context(rows, tmp_path)) == BURN_IN_S
    short = rows[rows["t"] < 120.0]
    assert burn_in(_context(short, tmp_path, duration_s=120.0)) == 60.0
    lines = filter_report(_context(short, tmp_path, duration_s=120.0))
    assert "t >= 60 s" in lines[2]
    # Epochs 60-119 carry 10 deg errors for the paper filter and 4 deg for mekf_snr.
    assert "ratio 0.400: **met**" in _line(lines, "- **(a) Accuracy**")


def test_nees_interval_is_the_chi_square_interval_of_the_run_average():
    lo, hi = nees_interval(100)
    assert lo == pytest.approx(chi2.ppf(0.025, 300) / 100)
    assert hi == pytest.approx(chi2.ppf(0.975, 300) / 100)
    assert lo < 3.0 < hi
    rows = pd.DataFrame(
        {"trial_index": [0, 1, 0, 1, 0], "t": [0.0, 0.0, 1.0, 1.0, 2.0], "nees": [1, 3, 2, 6, 9]}
    )
    averaged, trials = run_averaged_nees(rows)
    assert trials == 2
    assert averaged.to_dict() == {0.0: 2.0, 1.0: 4.0}  # epoch 2 lacks trial 1


def test_without_the_paper_filter_nothing_breaks(tmp_path):
    rows = _rows(filters=["mekf_snr", "rts_snr"])
    lines = filter_report(_context(rows, tmp_path, duration_s=3600.0))
    text = "\n".join(lines)
    assert "Target **met** (slowest: mekf_snr)" in text
    assert "Table 2's MEKF" not in text
    assert "not assessed (no valid settled mekf_snr or mekf_paper rows)" in text
    assert "- **(c) NEES consistency** (target" in text  # mekf_snr is still checked
    assert (tmp_path / "filter_errors_mems.png").exists()


def test_bias_figure_uses_estimates_when_the_rows_have_them(tmp_path):
    rows = _rows(**{f"bias_{a}_deg_h": 5.0 for a in AXES})
    rows.loc[rows["gyro"] == "none", [f"bias_{a}_deg_h" for a in AXES]] = np.nan
    lines = filter_report(_context(rows, tmp_path))
    assert "not the bias estimate" not in "\n".join(lines)
    assert (tmp_path / "gyro_bias_seed000.png").exists()


def test_modules_import_in_either_order():
    root = Path(__file__).resolve().parents[1]
    for first, second in (
        ("attopt.experiments.adsb_snr.filter_report", "attopt.experiments.adsb_snr.report"),
        ("attopt.experiments.adsb_snr.report", "attopt.experiments.adsb_snr.filter_report"),
    ):
        code = f"import {first}, {second}; {second}.__name__"
        subprocess.run([sys.executable, "-c", code], cwd=root, check=True)
