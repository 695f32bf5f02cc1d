"""Unit vectors of a pass as fixed slots: the arrays Yang et al. 2014's compiled passes take.

The EKF's compiled pass (:func:`attopt.solvers.doa.ekf.run_vectors`), its
posterior bound (:mod:`attopt.solvers.doa.eks`) and the batch least squares
(:mod:`attopt.solvers.doa.batch_ls`) run whole epochs of unit vectors in
CasADi with a fixed number of slots per epoch: :func:`vector_slots` gathers
them from a pass's snapshots, :func:`vector_arrays` moves the present ones to
the front, cuts the slots to the most at any epoch and turns the sigmas into
weights (zero for an absent slot).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.snapshot import Snapshot

Array = NDArray[np.float64]


def vector_arrays(
    body: ArrayLike, reference: ArrayLike, sigma: ArrayLike
) -> tuple[Array, Array, Array]:
    """Unit-vector slots as :func:`attopt.solvers.doa.ekf.epoch_function` takes them:
    ``(body, reference, weight)``.

    ``body`` and ``reference`` ``(N, S, 3)``, ``sigma`` ``(N, S)`` (or
    broadcastable); a slot is present where its body and reference vectors
    are finite (:class:`~attopt.formulations.attitude_measurement.VectorMeasurement`'s
    rule).  Each epoch's present vectors are moved to the front, in their
    order, and the slots cut to the largest count at any epoch (at least one):
    the epoch's cost grows with the slots, not with the stations.  Absent slots
    get finite placeholders and weight zero; present ones ``1 / sigma^2``.

    Raises:
        InvalidObservationError: bad shapes, or a present vector with a
            non-positive or non-finite sigma or a zero reference.
    """
    body = np.asarray(body, dtype=float)
    reference = np.asarray(reference, dtype=float)
    if body.ndim != 3 or body.shape[-1] != 3 or reference.shape != body.shape:
        raise InvalidObservationError(
            f"body {body.shape} and reference {reference.shape} must both be (N, S, 3)"
        )
    try:
        sigma = np.broadcast_to(np.asarray(sigma, dtype=float), body.shape[:2])
    except ValueError:
        raise InvalidObservationError(f"sigma must broadcast to {body.shape[:2]}") from None
    present = np.isfinite(body).all(axis=-1) & np.isfinite(reference).all(axis=-1)
    if not (np.all(np.isfinite(sigma[present])) and np.all(sigma[present] > 0)):
        raise InvalidObservationError("vector standard deviations must be finite and positive")
    if np.any(np.linalg.norm(reference[present], axis=-1) == 0):
        raise InvalidObservationError("reference vectors must be non-zero")
    slots = max(int(present.sum(axis=1).max(initial=0)), 1)
    order = np.argsort(~present, axis=1, kind="stable")[:, :slots]
    present = np.take_along_axis(present, order, axis=1)
    weight = np.where(present, 1.0 / np.take_along_axis(sigma, order, axis=1) ** 2, 0.0)
    placeholder = np.array([0.0, 0.0, 1.0])
    return (
        np.where(
            present[..., None], np.take_along_axis(body, order[..., None], axis=1), placeholder
        ),
        np.where(
            present[..., None], np.take_along_axis(reference, order[..., None], axis=1), placeholder
        ),
        weight,
    )


def unit_vectors_only(snapshots: Sequence[Snapshot | None]) -> bool:
    """Whether every measurement is a
    :class:`~attopt.formulations.attitude_measurement.VectorMeasurement` with
    per-vector sigmas (what :func:`vector_slots` takes)."""
    return all(
        isinstance(m, VectorMeasurement) and np.ndim(m.noise_covariance) == 1
        for s in snapshots
        if s is not None
        for m in s.measurements
    )


def vector_slots(snapshots: Sequence[Snapshot | None]) -> tuple[Array, Array, Array]:
    """Each epoch's unit vectors as ``(body, reference, sigma)``, ``(N, S, 3)``, ``(N, S, 3)``,
    ``(N, S)``, ``S`` the most at any epoch (at least one): the vectors of the
    epoch's :class:`~attopt.formulations.attitude_measurement.VectorMeasurement`s in
    order, then NaN rows (sigma 1) for absent ones (:func:`vector_arrays`).

    Raises:
        InvalidObservationError: a measurement that is not such a vector
            measurement (:func:`unit_vectors_only`).
    """
    if not unit_vectors_only(snapshots):
        raise InvalidObservationError("the compiled pass takes unit vectors with sigmas only")
    parts = [() if s is None else s.measurements for s in snapshots]
    counts = [sum(m.reference.shape[0] for m in p) for p in parts]
    slots = max(max(counts, default=0), 1)
    body = np.full((len(parts), slots, 3), np.nan)
    reference = np.full((len(parts), slots, 3), np.nan)
    sigma = np.ones((len(parts), slots))
    for k, (p, count) in enumerate(zip(parts, counts, strict=True)):
        if count:
            body[k, :count] = np.concatenate([m.z.reshape(-1, 3) for m in p])
            reference[k, :count] = np.concatenate([m.reference for m in p])
            sigma[k, :count] = np.concatenate([m.sigma for m in p])
    return body, reference, sigma
