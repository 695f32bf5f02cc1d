"""Multiplicative Rauch-Tung-Striebel smoothing: one backward pass for every filter's track.

:func:`rts_backward` is the fixed-interval backward pass of a multiplicative
error-state filter, on arrays.  With ``P_k`` the filtered covariance,
``P^-_{k+1}`` the predicted one and ``Phi_k`` the transition from epoch ``k``
to ``k + 1``,

    C_k = P_k Phi_k^T (P^-_{k+1})^-1,
    x_k = C_k [x^s_{k+1} (-) x^-_{k+1}],
    P^s_k = P_k + C_k (P^s_{k+1} - P^-_{k+1}) C_k^T,

where ``x_k`` is the smoothed state's offset from the filtered one (``A^s_k =
C(x_k[a]) A_k`` in the attitude block ``a``, sums elsewhere, ``C(delta) A`` the
attitude :func:`~attopt.solvers.filters.common.apply_error` gives) and ``(-)`` the
error state of the smoothed estimate relative to the predicted one: the
attitude error vector (:func:`~attopt.solvers.filters.common.error_vector`, four times
the MRPs of ``A^s (A^-)^T``, body frame of epoch ``k + 1``, where ``Phi`` maps
the error to) and differences elsewhere.  Since ``A^s_{k+1} = C(x_{k+1})
A_{k+1}`` and ``A_{k+1} = C(c_{k+1}) A^-_{k+1}`` (``c`` the filter's
correction), the attitude part is the error vector of the composition ``C(x)
C(c)``, computed from quaternions in CasADi (:func:`composed_error`), so the
whole pass runs in CasADi, as a compiled kernel
(:func:`~attopt.solvers.filters.casadi_pass.accumulate`).  ``P^s_{k+1} <= P^-_{k+1}``
makes ``P^s_k <= P_k``: the smoothed covariance never exceeds the filtered one.

The pass knows only where the attitude block sits.  :func:`rts_smooth` runs it
on a filter's :class:`~attopt.solvers.results.Track` with its
:class:`~attopt.solvers.sequential.FilterHistory`, the attitude block found
from the track's ``state``: the gyro MEKF's (state ``[delta, delta_beta]``,
``a = 0:3``; the filter-based smoothing baseline ``rts``) and Yang et al.
2014's EKF's (state ``[delta_omega, delta]``, ``a = 3:6``; ``rts_yang2014``).
For the EKF this is its own error: :func:`~attopt.solvers.filters.common.apply_error`
is its update's retraction ``C(delta) A``
(:func:`~attopt.formulations.attitude_model.increment_matrix`) and ``Phi``
maps first-order body-frame rotation vectors, which the error vector is to
first order.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import InvalidObservationError
from attopt.solvers.filters.casadi_pass import accumulate, lower_symmetric
from attopt.solvers.filters.common import FilterOptions, apply_error, error_vector
from attopt.solvers.results import Track
from attopt.solvers.sequential import EpochRecord, filter_result, rotations

Array = NDArray[np.float64]


def _quaternion(error: Any) -> tuple[Any, Any]:
    """Vector part and scalar of the (scalar-last) quaternion of ``C(error)``: MRPs
    ``p = error / 4``, ``q = [2 p, 1 - |p|^2] / (1 + |p|^2)``."""
    p = error / 4.0
    norm2 = ca.dot(p, p)
    return 2.0 * p / (1.0 + norm2), (1.0 - norm2) / (1.0 + norm2)


def composed_error(outer: Any, inner: Any) -> Any:
    """``error_vector(apply_error(outer, apply_error(inner, A)), A)`` in CasADi (``3 x 1``).

    Four times the MRPs of ``C(outer) C(inner)``: the Hamilton product of the
    two quaternions, the shadow set taken when its scalar is negative (as
    scipy's ``as_mrp``).
    """
    v1, w1 = _quaternion(outer)
    v2, w2 = _quaternion(inner)
    vector = w1 * v2 + w2 * v1 + ca.cross(v1, v2)
    scalar = w1 * w2 - ca.dot(v1, v2)
    sign = ca.if_else(scalar < 0, -1.0, 1.0)
    return 4.0 * sign * vector / (1.0 + sign * scalar)


@lru_cache(maxsize=8)
def _backward_function(size: int, attitude_start: int) -> ca.Function:
    """``(x_next, P^s_next, C, P, P^-_next, c_next) -> (x, P^s)``: one RTS step back."""
    offset = ca.SX.sym("offset", size)
    smoothed = ca.SX.sym("smoothed", size, size)
    gain = ca.SX.sym("gain", size, size)
    filtered = ca.SX.sym("filtered", size, size)
    predicted = ca.SX.sym("predicted", size, size)
    correction = ca.SX.sym("correction", size)
    block = slice(attitude_start, attitude_start + 3)
    difference = offset + correction
    difference[block] = composed_error(offset[block], correction[block])
    covariance = filtered + gain @ (smoothed - predicted) @ gain.T
    return ca.Function(
        "rts_backward_step",
        [offset, smoothed, gain, filtered, predicted, correction],
        [ca.densify(gain @ difference), ca.densify(lower_symmetric(covariance))],
        {"cse": True},
    )


def rts_backward(
    filtered_covariance: ArrayLike,
    predicted_covariance: ArrayLike,
    transition: ArrayLike,
    correction: ArrayLike,
    attitude_start: int,
) -> tuple[Array, Array]:
    """The multiplicative RTS backward pass (module docstring) on arrays.

    Args:
        filtered_covariance: ``(N, n, n)`` ``P_k`` after epoch ``k``'s update.
        predicted_covariance: ``(N, n, n)`` ``P^-_k`` before it (row 0 unused).
        transition: ``(N - 1, n, n)``, ``transition[k]`` from epoch ``k`` to ``k + 1``.
        correction: ``(N, n)`` filtered minus predicted state at each epoch:
            the attitude error vector (:func:`~attopt.solvers.filters.common.error_vector`
            of the filtered attitude relative to the predicted one) in the
            attitude block, plain differences elsewhere (row 0 unused).
        attitude_start: index of the three attitude-error components.

    Returns:
        ``(N, n)`` offsets of the smoothed state from the filtered one (zero at
        the last epoch; apply the attitude block with
        :func:`~attopt.solvers.filters.common.apply_error`) and the ``(N, n, n)``
        smoothed covariances.
    """
    filtered_covariance = np.asarray(filtered_covariance, dtype=float)
    predicted_covariance = np.asarray(predicted_covariance, dtype=float)
    transition = np.asarray(transition, dtype=float)
    correction = np.asarray(correction, dtype=float)
    n, size = correction.shape
    if (
        filtered_covariance.shape != (n, size, size)
        or predicted_covariance.shape != (n, size, size)
        or transition.shape != (n - 1, size, size)
    ):
        raise InvalidObservationError("inconsistent shapes for the RTS pass")
    # C_k^T = (P^-_{k+1})^-1 Phi_k P_k, all epochs at once
    gain = np.linalg.solve(predicted_covariance[1:], transition @ filtered_covariance[:-1])
    gain = np.swapaxes(gain, 1, 2)
    backward = np.s_[::-1]
    offsets, covariances = accumulate(
        _backward_function(size, attitude_start),
        2,
        [np.zeros(size), filtered_covariance[-1]],
        [
            gain[backward],
            filtered_covariance[:-1][backward],
            predicted_covariance[1:][backward],
            correction[1:][backward],
        ],
        n - 1,
    )
    return (
        np.concatenate([offsets[backward, :, 0], np.zeros((1, size))]),
        np.concatenate([covariances[backward], filtered_covariance[-1:]]),
    )


def rts_smooth(filtered: Track, options: FilterOptions, method: str) -> Track:
    """Smoothed estimates at a smoothable filter's epochs: :func:`rts_backward` over each
    run of epochs the filter reports valid (:func:`valid_segments`; epochs after a
    divergence stay invalid, and so do the epochs the filter flagged), with ``options``'
    validity rules.

    Raises:
        InvalidObservationError: ``filtered`` has no history (not a smoothable filter's).
    """
    history = filtered.history
    if history is None:
        raise InvalidObservationError(
            "the RTS pass needs a filter track with its history (an MEKF's or an EKF's)"
        )
    n = len(filtered)
    record = EpochRecord(n, filtered.state, tuple(filtered.diagnostics))
    record.diagnostics = dict(filtered.diagnostics)
    record.reason = np.where(filtered.valid, "", filtered.reason)
    attitude = filtered.block("attitude")
    other = next(name for name in filtered.state if name != "attitude")
    vector = filtered.block(other)
    values = np.asarray(history.filtered_attitude).reshape(n, -1)
    finite = np.flatnonzero(np.isfinite(values).all(axis=1))
    if finite.size == 0:
        return filter_result(method, record, options, filtered.t)
    end = finite[-1] + 1
    after = rotations(history.filtered_attitude[:end])
    correction = np.zeros((end, 3 * len(filtered.state)))
    correction[:, attitude] = error_vector(after, rotations(history.predicted_attitude[:end]))
    correction[:, vector] = history.filtered_vector[:end] - history.predicted_vector[:end]
    record.quaternion = filtered.quaternion.copy()
    record.vector = np.array(getattr(filtered, other), dtype=float)
    record.covariance = np.array(filtered.state_covariance, dtype=float)
    for a, b in valid_segments(filtered.valid[:end]):
        offset, covariance = rts_backward(
            history.filtered_covariance[a:b],
            history.predicted_covariance[a:b],
            history.transition[a + 1 : b],
            correction[a:b],
            attitude_start=attitude.start,
        )
        record.quaternion[a : b - 1] = apply_error(
            offset[:-1, attitude], after[a : b - 1]
        ).as_quat()
        record.vector[a:b] += offset[:, vector]
        record.covariance[a:b] = covariance
    return filter_result(method, record, options, filtered.t)


def valid_segments(valid: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """The ``[start, stop)`` runs of consecutive valid epochs: the backward pass smooths
    each on its own, so that the state of a flagged stretch (a lost track, innovations
    that contradict the covariance) never reaches the epochs before it.

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.filters.rts import valid_segments
        >>> valid_segments(np.array([True, True, False, True, False, False, True]))
        [(0, 2), (3, 4), (6, 7)]
    """
    edges = np.diff(np.concatenate([[0], np.asarray(valid, dtype=np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()
    return list(zip(starts, stops, strict=True))
