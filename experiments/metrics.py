"""Per-epoch error metrics of a batch solution against the truth, shared by experiments.

Columns (``docs/conventions.md``): ``err_{x,y,z}_deg`` the body-axis
components of the rotation vector of ``estimate * truth.inv()``;
``sigma_{x,y,z}_deg`` the square roots of the diagonal of the method's own
covariance; ``nees`` the normalised estimation error squared ``e^T P^-1 e``
(NaN where the covariance is not finite); ``euler_{yaw,pitch,roll}_err_deg``
the 3-2-1 Euler-angle differences (seed 000 eq. 8) wrapped to [-180, 180),
which the seeds' tables report.  Invalid epochs are NaN throughout.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error, euler321_from_attitude
from attopt.solvers.results import Track

AXES = ("x", "y", "z")


def error_columns(solution: Track, truth: Rotation) -> dict[str, np.ndarray]:
    """Error, own-sigma, NEES and Euler-difference columns for every epoch (deg)."""
    n = len(solution)
    valid = solution.valid
    error = np.full((n, 3), np.nan)
    euler = np.full((n, 3), np.nan)
    nees = np.full(n, np.nan)
    if valid.any():
        estimate = solution.attitude()
        error[valid] = attitude_error(estimate, truth[valid])
        diff = np.degrees(euler321_from_attitude(estimate) - euler321_from_attitude(truth[valid]))
        euler[valid] = (diff + 180.0) % 360.0 - 180.0
        covariance = solution.covariance[valid]
        finite = np.isfinite(covariance).all(axis=(1, 2))
        e = error[valid][finite]
        nees_valid = np.full(int(valid.sum()), np.nan)
        nees_valid[finite] = np.einsum("ei,eij,ej->e", e, np.linalg.inv(covariance[finite]), e)
        nees[valid] = nees_valid
    sigma = np.degrees(np.sqrt(np.diagonal(solution.covariance, axis1=1, axis2=2)))
    columns = {f"err_{a}_deg": np.degrees(error[:, i]) for i, a in enumerate(AXES)}
    columns |= {f"sigma_{a}_deg": sigma[:, i] for i, a in enumerate(AXES)}
    columns["nees"] = nees
    for i, name in enumerate(("yaw", "pitch", "roll")):
        columns[f"euler_{name}_err_deg"] = euler[:, i]
    return columns
