"""Names of the ``doa-ground`` rows, shared by the experiment and its report."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from attopt.solvers.doa.ekf import PROCESS_NOISE

GYRO_FILTERS = ("mekf", "fg_batch")
"""Default ``filters``: the gyro-aided MEKF and the factor-graph smoother."""
SMOOTHER = "fg_batch"
BATCH_LS = "bls_seed003"
"""Whole-pass batch least squares over Yang et al. 2014's dynamics (``Q = 0``)."""
SUBSET_METHODS = (BATCH_LS, *GYRO_FILTERS)
"""Methods that run only in the first ``filter_trials`` trials of a setting."""


def ekf_method(q: float) -> str:
    """Method name of Yang et al. 2014's EKF with process noise ``q``."""
    return f"ekf_seed003_q{q:.0e}"


def rts_method(q: float) -> str:
    """Method name of the RTS smoother over the EKF with process noise ``q``."""
    return f"rts_seed003_q{q:.0e}"


def process_noises(parameters: Mapping[str, Any]) -> list[float]:
    """The EKFs' ``Q`` values; the first is the paper's (default its 1e-9 alone)."""
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
