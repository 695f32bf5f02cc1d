"""The ``doa-ground`` rows: their labels, the registry estimators they run and their order.

One place maps each row label to a registry estimator with its options
(:mod:`attopt.solvers.registry`), shared by the experiment and its report:

* ``ekf_yang2014_q<Q>`` and ``rts_yang2014_q<Q>`` (:func:`dynamics_estimators`):
  Yang et al. 2014's EKF (``ekf_yang2014``) with ``Q = q E_6`` and the RTS
  pass over it (``rts_yang2014``);
* ``bls_yang2014`` (:func:`batch_ls_estimator`): the whole-pass batch least
  squares, an unconverged pass's estimates kept;
* ``wahba`` (:data:`WAHBA`): the SVD solution of Wahba's problem (``svd``);
* the gyro-aided ``filters`` by their registry names (:func:`filter_labels`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from attopt.experiments.estimators import Options, configured, registered_labels
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.solvers.doa.batch_ls import BatchLsOptions
from attopt.solvers.doa.ekf import PROCESS_NOISE
from attopt.solvers.estimator import Estimator

GYRO_FILTERS = ("mekf", "fg_batch")
"""Default ``filters``: the gyro-aided MEKF and the factor-graph smoother."""
SMOOTHER = "fg_batch"
BATCH_LS = "bls_yang2014"
"""Whole-pass batch least squares over Yang et al. 2014's dynamics (``Q = 0``)."""
SUBSET_METHODS = (BATCH_LS, *GYRO_FILTERS)
"""Methods that run only in the first ``filter_trials`` trials of a setting."""
WAHBA = {"wahba": "svd"}
"""The single-epoch row and the registry estimator it runs."""


def ekf_method(q: float) -> str:
    """Row label of Yang et al. 2014's EKF with process noise ``q``."""
    return f"ekf_yang2014_q{q:.0e}"


def rts_method(q: float) -> str:
    """Row label of the RTS smoother over the EKF with process noise ``q``."""
    return f"rts_yang2014_q{q:.0e}"


def dynamics_estimators(q: float, options: Options | None = None) -> dict[str, Estimator]:
    """The EKF with ``Q = q E_6`` and the RTS pass over it, by row label, each with its
    ``estimator_options`` (``options``) but for ``Q`` (the ``process_noise`` parameter's)
    and the RTS pass's forward filter (this EKF)."""
    ekf = replace(configured("ekf_yang2014", options or {}), process_noise=q)
    rts = replace(configured("rts_yang2014", options or {}), forward=ekf)
    return {ekf_method(q): ekf, rts_method(q): rts}


def batch_ls_estimator(options: Options | None = None) -> Estimator:
    """``bls_yang2014`` with an unconverged pass's estimates kept (its rows are flagged with
    the report's reason), then its ``estimator_options`` (``options``)."""
    return configured(BATCH_LS, options or {}, batch=BatchLsOptions(flag_unconverged=False))


def filter_labels() -> dict[str, str]:
    """Row label -> registry name of the ``filters``: the pass estimators that accept unit
    vectors, by name."""
    return registered_labels("pass", VectorMeasurement)


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
        *WAHBA,
        *parameters.get("filters", GYRO_FILTERS),
    ]
    present = set(rows["method"])
    return [m for m in dict.fromkeys(candidates) if m in present]
