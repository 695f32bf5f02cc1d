"""The filter tables of the adsb-snr report on synthetic rows with hand-computable errors.

After the burn-in every ``mekf_paper`` error component is +/-1 deg (10 deg before), the
``nlse`` input's 1.5 times that, ``mekf_snr``'s ``snr_scale`` times it and every other
filter's 0.3 times it; every sigma is 1 deg, every NEES 3 unless a test says otherwise.
The single-frame tables are checked on a real sweep in ``tests/test_adsb_experiment.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.adsb_snr.experiment import EXPERIMENT
from attopt.experiments.adsb_snr.report import (
    BURN_IN_S,
    burn_in,
    figures,
    filter_section,
    report,
)
from attopt.experiments.experiment import ReportContext
from attopt.experiments.reporting.statistics import nees_interval
from tests.report_tables import row, table

FILTERS = ["mekf_paper", "mekf_snr", "usque_snr", "rts_snr", "fg_batch"]
GYROS = ["liu2023", "mems"]
N_EPOCHS = 700
AXES = ("x", "y", "z")


def _frame(method: str, gyro: str, trial: int, error: np.ndarray, **extra) -> pd.DataFrame:
    """Rows of one method and trial with per-epoch body errors ``error`` (N, 3), deg."""
    frame = {
        "setting_index": 0,
        "trial_index": trial,
        "method": method,
        "gyro": gyro,
        "t_s": np.arange(N_EPOCHS, dtype=float),
        "valid": True,
        "reason": "",
        "runtime_s": extra.pop("runtime_s", 1.0),
        "nees": extra.pop("nees", 3.0),
    }
    for i, axis in enumerate(AXES):
        frame[f"err_{axis}_deg"] = error[:, i]
        frame[f"sigma_{axis}_deg"] = 1.0
        frame[f"pbound_{axis}_deg"] = 0.3
    for i, name in enumerate(("roll", "pitch", "yaw")):
        frame[f"euler_{name}_err_deg"] = error[:, i]
    if gyro != "none":
        for axis in AXES:
            frame[f"bias_err_{axis}_deg_h"] = 1.0
            frame[f"bias_sigma_{axis}_deg_h"] = 2.0
        frame |= {"nees_full": 6.0, "n_used": 100.0, "n_gated": 1.0, "n_unpredictable": 0.0}
    return pd.DataFrame(frame | extra)


def _rows(filters=FILTERS, trials: int = 2, snr_scale: float = 0.4, nees: float = 3.0):
    rng = np.random.default_rng(0)
    frames = []
    for trial in range(trials):
        signs = rng.choice([-1.0, 1.0], size=(N_EPOCHS, 3))
        base = signs * np.where(np.arange(N_EPOCHS) < BURN_IN_S, 10.0, 1.0)[:, None]
        frames.append(_frame("nlse", "none", trial, 1.5 * base, runtime_s=4.0))
        for gyro in GYROS:
            for method in filters:
                scale = {"mekf_paper": 1.0, "mekf_snr": snr_scale}.get(method, 0.3)
                frames.append(
                    _frame(method, gyro, trial, scale * base, runtime_s=2.0 + trial, nees=nees)
                )
    return pd.concat(frames, ignore_index=True)


def _context(rows: pd.DataFrame, out: Path, **parameters) -> ReportContext:
    base = EXPERIMENT.parameters | {
        "duration_s": float(N_EPOCHS),
        "step_s": 1.0,
        "filters": FILTERS,
        "gyros": GYROS,
        "initial_sigma_deg": 10.0,
        "paper_sigma_deg": 1.0,
    }
    return ReportContext({**base, **parameters}, rows, pd.DataFrame(), out, "attopt run adsb-snr")


def test_no_filter_rows_gives_no_section(tmp_path):
    rows = _rows(filters=[])
    assert filter_section(_context(rows, tmp_path)) == ""
    assert filter_section(_context(rows.drop(columns="gyro"), tmp_path)) == ""


def test_table2_row_of_the_papers_filter(tmp_path):
    text = filter_section(_context(_rows(), tmp_path))
    paper = table(text, "Liu et al. 2023 Table 2's MEKF beside mekf_paper")
    mekf = row(paper, {"row": "MEKF (Liu et al. 2023 Table 2)"})
    assert mekf["RMS yaw / pitch / roll (deg)"] == "0.28 / 0.15 / 0.24"
    assert mekf["max yaw / pitch / roll (deg)"] == "1.46 / -1.31 / 2.40"
    where = {"row": "mekf_paper, gyro liu2023", "epochs": f"t >= {BURN_IN_S:g} s"}
    settled = row(paper, where | {"errors": "Euler"})
    assert settled["RMS yaw / pitch / roll (deg)"] == "1.00 / 1.00 / 1.00"
    assert row(paper, {"row": "mekf_paper, gyro mems", "epochs": "all", "errors": "body z/y/x"})[
        "RMS yaw / pitch / roll (deg)"
    ] == " / ".join([f"{np.sqrt((300 * 100 + 400) / 700):.2f}"] * 3)
    assert settled["runtime (s)"] == "2.5"
    # the input: 1.5 deg errors; the filter's own sigma 1 deg against Table 2's RMS
    inputs = table(text, "mekf_paper and its input")
    filtered = row(inputs, {"row": "mekf_paper, gyro liu2023"})
    assert filtered["RMS / nlse RMS yaw / pitch / roll"] == "0.67 / 0.67 / 0.67"
    assert filtered["own sigma / Table 2 MEKF RMS yaw / pitch / roll"] == "3.57 / 6.67 / 4.17"
    assert row(inputs, {"row": "MEKF / NLSE (Liu et al. 2023 Table 2)"}).iloc[1] == (
        "0.23 / 0.18 / 0.16"
    )


def test_filters_compared_after_the_burn_in(tmp_path):
    text = filter_section(_context(_rows(snr_scale=0.6), tmp_path))
    compared = table(text, "Filters compared")
    snr = row(compared, {"gyro": "liu2023", "method": "mekf_snr"})
    assert snr["RMS roll / pitch / yaw (deg)"] == "0.600 / 0.600 / 0.600"
    assert snr["RMS / mekf_paper RMS"] == "0.600"
    assert snr["gated / unpredictable / used observations"] == (
        f"{2 * N_EPOCHS:,} / 0 / {100 * 2 * N_EPOCHS:,}"
    )
    assert snr["runtime (s per pass), mean (max)"] == "2.50 (3.00)"
    reference = row(compared, {"gyro": "none", "method": "nlse"})
    assert reference["RMS roll / pitch / yaw (deg)"] == "1.500 / 1.500 / 1.500"
    assert reference["gated / unpredictable / used observations"] == "-"
    smoothers = table(text, "Factor-graph smoothers")
    fg = row(smoothers, {"gyro": "mems", "method": "fg_batch"})
    total = 0.3 * np.sqrt(3.0)
    assert fg.iloc[2:6].tolist() == [f"{total:.3f}", f"{total:.3f}", "1.00", "0.300"]


@pytest.mark.parametrize("nees", [3.0, 20.0])
def test_run_averaged_nees_against_its_interval(tmp_path, nees):
    text = filter_section(_context(_rows(nees=nees), tmp_path))
    averaged = table(text, "Run-averaged NEES")
    lo, hi = nees_interval(2)
    assert set(averaged["95% interval"]) == {f"[{lo:.3f}, {hi:.3f}]"}
    assert set(averaged["run- and time-averaged NEES"]) == {f"{nees:.3f}"}
    assert set(averaged["epochs inside"]) == {"1.000" if lo <= nees <= hi else "0.000"}
    assert len(averaged) == 4  # two filters x two gyros


def test_burn_in_is_at_most_half_the_pass(tmp_path):
    rows = _rows()
    assert burn_in(_context(rows, tmp_path)) == BURN_IN_S
    short = rows[rows["t_s"] < 120.0]
    context = _context(short, tmp_path, duration_s=120.0)
    assert burn_in(context) == 60.0
    text = filter_section(context)
    assert "Valid epochs at t >= 60 s" in text
    # epochs 60-119 carry 10 deg errors for the paper filter and 4 deg for mekf_snr
    snr = row(table(text, "Filters compared"), {"gyro": "mems", "method": "mekf_snr"})
    assert snr["RMS / mekf_paper RMS"] == "0.400"


def test_filter_figures_are_written(tmp_path):
    names = figures(_context(_rows(), tmp_path), [])
    assert names == [f"{k}_{g}.png" for g in GYROS for k in ("filter_errors", "gyro_bias")]
    for name in names:
        assert (tmp_path / name).stat().st_size > 10_000


def test_a_filters_only_run_reports_the_filters_and_integrity(tmp_path):
    """The filter benchmark's sweep has no single-frame rows (``methods = []``)."""
    rows = _rows(filters=["mekf_snr", "rts_snr"])
    rows = rows[rows["gyro"] != "none"]
    text = report(_context(rows, tmp_path, methods=[], filters=["mekf_snr", "rts_snr"]))
    assert "## Gyro-aided filters" in text and "Table 2 beside ours" not in text
    integrity = table(text, "Integrity")
    assert set(integrity["method"]) == {"mekf_snr", "rts_snr"}
    assert set(integrity["mean NEES"]) == {"3"} and set(integrity["share beyond 21.1"]) == {"0"}
    assert (
        row(table(text, "Filters compared"), {"gyro": "mems", "method": "rts_snr"})[
            "RMS / mekf_paper RMS"
        ]
        == "-"
    )
