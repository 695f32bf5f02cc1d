"""Experiment ``wahba-mag-sun``: every Wahba solver on seed 002's scenario.

One trial is one pass of :mod:`experiments.scenarios.wahba_mag_sun` (6000 s
at 1 Hz) with fresh sensor noise; every solver sees the same measurements.
Rows are per method and epoch: the body-axis attitude error, the Cramer-Rao
bound of that epoch (``sqrt`` of the diagonal of ``[sum a_i (I - b_i b_i^T)]^-1``
at the true body vectors) and the method's own covariance (as ``sigma_*`` and
the normalised estimation error squared ``nees``), and the 3-2-1 Euler-angle
differences the seed's Table 1 reports.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from experiments.experiment import Experiment, Setting
from experiments.metrics import error_columns
from experiments.scenarios.wahba_mag_sun import (
    MAG_SIGMA,
    SUN_SIGMA,
    VectorGeometry,
    build_geometry,
    simulate_measurements,
)
from experiments.wahba_report import report
from formulations.wahba_covariance import quest_covariance
from solvers.wahba import WAHBA_SOLVERS

INTERVALS = ("before_eclipse", "eclipse", "after_eclipse")

PARAMETERS: dict[str, Any] = {
    "duration_s": 6000.0,
    "step_s": 1.0,
    "mag_sigma": MAG_SIGMA,
    "sun_sigma": SUN_SIGMA,
    "methods": list(WAHBA_SOLVERS),
}


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting: the seed's sensor noise; methods are compared inside each trial."""
    unknown = sorted(set(parameters["methods"]) - set(WAHBA_SOLVERS))
    if unknown:
        raise ValueError(f"unknown methods {unknown}; registered: {sorted(WAHBA_SOLVERS)}")
    return [dict(parameters)]


def interval_labels(geometry: VectorGeometry) -> np.ndarray:
    """``before_eclipse``, ``eclipse`` or ``after_eclipse`` per epoch."""
    labels = np.full(geometry.t.shape, INTERVALS[0], dtype=object)
    if geometry.eclipse_interval is not None:
        start, end = geometry.eclipse_interval
        labels[geometry.t >= start] = INTERVALS[1]
        labels[geometry.t >= end] = INTERVALS[2]
    return labels


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method in ``setting["methods"]``."""
    geometry = build_geometry(setting["duration_s"], setting["step_s"])
    sun_body, mag_body = simulate_measurements(
        geometry,
        np.random.default_rng(seed),
        mag_sigma=setting["mag_sigma"],
        sun_sigma=setting["sun_sigma"],
    )
    n = geometry.t.size
    body = np.stack([sun_body, mag_body], axis=1)
    reference = np.stack([geometry.sun_orbit, geometry.mag_orbit], axis=1)
    weights = np.tile([setting["sun_sigma"] ** -2, setting["mag_sigma"] ** -2], (n, 1))
    present = np.stack([~geometry.in_eclipse, np.ones(n, dtype=bool)], axis=1)

    true_body = np.stack(
        [geometry.truth.apply(geometry.sun_orbit), geometry.truth.apply(geometry.mag_orbit)], axis=1
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        crb = _safe_inverse_diag(true_body, np.where(present, weights, 0.0))
    common = {
        "t": geometry.t,
        "interval": interval_labels(geometry),
        "bound_x_deg": np.degrees(np.sqrt(crb[:, 0])),
        "bound_y_deg": np.degrees(np.sqrt(crb[:, 1])),
        "bound_z_deg": np.degrees(np.sqrt(crb[:, 2])),
    }
    frames = [
        _method_rows(name, body, reference, weights, present, geometry, common)
        for name in setting["methods"]
    ]
    return pd.concat(frames, ignore_index=True)


def _safe_inverse_diag(true_body: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Diagonal of the Cramer-Rao bound; NaN where the information is singular."""
    info_rank_ok = (weights > 0).sum(axis=1) >= 2
    out = np.full((weights.shape[0], 3), np.nan)
    if info_rank_ok.any():
        cov = quest_covariance(true_body[info_rank_ok], weights[info_rank_ok])
        out[info_rank_ok] = np.diagonal(cov, axis1=1, axis2=2)
    return out


def _method_rows(
    name: str,
    body: np.ndarray,
    reference: np.ndarray,
    weights: np.ndarray,
    present: np.ndarray,
    geometry: VectorGeometry,
    common: Mapping[str, np.ndarray],
) -> pd.DataFrame:
    solution = WAHBA_SOLVERS[name].solve_batch(body, reference, weights, present)
    return pd.DataFrame(
        {
            "method": name,
            **common,
            **error_columns(solution, geometry.truth),
            "valid": solution.valid,
            "reason": solution.reason.astype(str),
        }
    )


EXPERIMENT = Experiment(
    name="wahba-mag-sun",
    summary="Seed 002: six Wahba solvers on TIMED with magnetometer + Sun sensor, vs the CRB",
    parameters=PARAMETERS,
    grid=grid,
    trial=trial,
    default_trials=20,
    quick_trials=2,
    quick_parameters={"duration_s": 3000.0},
    group_by=("method", "interval"),
    report=report,
)
