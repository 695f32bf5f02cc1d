"""Multiplicative Rauch-Tung-Striebel smoother over the MEKF (the filter-based smoothing baseline).

Backward pass on the output epochs of :func:`solvers.filters.mekf.mekf`, in
error-state form: with ``Phi_{k+1}`` the transition from epoch ``k`` to
``k + 1`` and ``P^-_{k+1}`` the predicted covariance there,

    C_k = P_k Phi_{k+1}^T (P^-_{k+1})^-1,
    x_k = C_k [delta(A^s_{k+1}, A^-_{k+1}); beta^s_{k+1} - beta^-_{k+1}],
    A^s_k = exp(x_k[:3]) A_k,  beta^s_k = beta_k + x_k[3:],
    P^s_k = P_k + C_k (P^s_{k+1} - P^-_{k+1}) C_k^T,

``delta`` the error vector of :mod:`solvers.filters.common` (body frame of
epoch ``k + 1``, where ``Phi`` maps the error to).  Since ``P^s_{k+1} <=
P^-_{k+1}``, the smoothed covariance never exceeds the filtered one.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from solvers.filters.common import (
    EpochRecord,
    FilterOptions,
    FilterResult,
    apply_error,
    error_vector,
    filter_result,
)


def rts_smooth(
    filtered: FilterResult, options: FilterOptions | None = None, method: str = "rts"
) -> FilterResult:
    """Smoothed estimates at the filter's epochs (epochs after a divergence stay invalid)."""
    history = filtered.history
    if history is None:
        raise ValueError("the RTS pass needs a filter result with its history (an MEKF's)")
    n = history.filtered_quaternion.shape[0]
    record = EpochRecord(n)
    record.diagnostics = dict(filtered.solution.diagnostics)
    record.reason = np.where(filtered.solution.valid, "", filtered.solution.reason)
    finite = np.flatnonzero(np.isfinite(history.filtered_quaternion).all(axis=1))
    if finite.size == 0:
        return filter_result(method, record, options or FilterOptions())
    last = finite[-1]
    quaternion = history.filtered_quaternion.copy()
    bias = history.filtered_bias.copy()
    covariance = history.filtered_covariance.copy()
    smoothed = Rotation.from_quat(quaternion[last])
    for k in range(last - 1, -1, -1):
        predicted = Rotation.from_quat(history.predicted_quaternion[k + 1])
        p_pred = history.predicted_covariance[k + 1]
        gain = np.linalg.solve(p_pred, history.transition[k + 1] @ covariance[k]).T
        delta = np.concatenate(
            [error_vector(smoothed, predicted), bias[k + 1] - history.predicted_bias[k + 1]]
        )
        correction = gain @ delta
        smoothed = apply_error(correction[:3], Rotation.from_quat(quaternion[k]))
        quaternion[k] = smoothed.as_quat()
        bias[k] = bias[k] + correction[3:]
        p = covariance[k] + gain @ (covariance[k + 1] - p_pred) @ gain.T
        covariance[k] = 0.5 * (p + p.T)
    record.quaternion, record.bias, record.covariance = quaternion, bias, covariance
    return filter_result(method, record, options or FilterOptions())
