"""Vector observations for Wahba's problem (Cilden Guler et al. 2017 sec. 2.3), validated.

A batch holds ``N`` epochs of up to ``n`` observation pairs: body-frame
measurements ``b_i`` and reference-frame directions ``r_i`` with weights
``a_i = 1 / sigma_i^2`` (Cilden Guler et al. 2017 eq. 14).  An observation missing at an epoch
(e.g. the Sun sensor in eclipse) is marked absent with the ``present`` mask.

Policy on bad input:

* malformed input as a whole (wrong shapes) raises
  :class:`~attopt.formulations.errors.InvalidObservationError` immediately;
* per-epoch problems (NaN/inf components, zero-length vectors, zero, negative
  or NaN weights, fewer than two observations, (anti)parallel directions) mark
  that epoch invalid with a reason and the exception class a single-epoch call
  raises, so one bad epoch does not sink a whole pass.

Non-unit vectors are normalised (a magnetometer measures a full field vector);
vectors shorter than ``MIN_NORM`` are rejected as zero-length.  Directions are
(anti)parallel when every pair has ``|b_i x b_j| < parallel_tolerance``
(default ``PARALLEL_TOLERANCE``, about 0.057 deg); the check runs on body and
reference vectors alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import AttoptError, InvalidObservationError, UnobservableError
from attopt.formulations.wahba import attitude_profile_matrix

MIN_NORM = 1e-12
PARALLEL_TOLERANCE = 1e-3

# A well-conditioned stand-in for invalid epochs so vectorised solvers never
# see NaN; their results are masked out afterwards.
_PLACEHOLDER = np.eye(3)


@dataclass(frozen=True)
class ObservationBatch:
    """Validated, normalised observations of ``N`` epochs.

    Attributes:
        body: ``(N, n, 3)`` unit body-frame vectors ``b_i``.
        reference: ``(N, n, 3)`` unit reference-frame vectors ``r_i``.
        weights: ``(N, n)`` weights ``a_i``; zero where an observation is absent.
        valid: ``(N,)`` whether the epoch determines an attitude.
        reason: ``(N,)`` why an epoch is invalid (empty string when valid).
        error: ``(N,)`` exception class a single-epoch call raises (None when valid).
    """

    body: NDArray[np.float64]
    reference: NDArray[np.float64]
    weights: NDArray[np.float64]
    valid: NDArray[np.bool_]
    reason: NDArray[np.object_]
    error: NDArray[np.object_]

    @property
    def n_epochs(self) -> int:
        return self.body.shape[0]

    @cached_property
    def profile_matrix(self) -> NDArray[np.float64]:
        """Attitude profile matrix ``B`` (Cilden Guler et al. 2017 eq. 15), once per batch."""
        return attitude_profile_matrix(self.body, self.reference, self.weights)

    def raise_if_invalid(self, epoch: int = 0) -> None:
        """Raise the specific exception recorded for ``epoch``, if any."""
        if not self.valid[epoch]:
            raise self.error[epoch](self.reason[epoch])


def as_batch(
    body: ArrayLike, reference: ArrayLike, weights: ArrayLike, present: ArrayLike | None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """``(N, n, 3)`` body and reference vectors, ``(N, n)`` weights and present mask; raises
    :class:`~attopt.formulations.errors.InvalidObservationError` on malformed shapes."""
    b = np.asarray(body, dtype=float)
    r = np.asarray(reference, dtype=float)
    a = np.asarray(weights, dtype=float)
    single = b.ndim == 2
    if not (single or b.ndim == 3) or b.shape[-1] != 3:
        raise InvalidObservationError(
            f"body vectors must have shape (n, 3) or (N, n, 3), got {b.shape}"
        )
    if r.shape != b.shape:
        raise InvalidObservationError(
            f"reference vectors have shape {r.shape}, body vectors {b.shape}: they must match"
        )
    if single:
        b, r = b[None], r[None]
        a = a[None] if a.ndim == 1 else a
    if a.shape != b.shape[:2]:
        raise InvalidObservationError(
            f"weights must have one entry per observation, shape {b.shape[:2]}, got {a.shape}"
        )
    if present is None:
        p = np.ones(a.shape, dtype=bool)
    else:
        p = np.asarray(present, dtype=bool)
        p = p[None] if single and p.ndim == 1 else p
    if p.shape != a.shape:
        raise InvalidObservationError(f"present mask must have shape {a.shape}, got {p.shape}")
    return b, r, a, p


def _max_pairwise_cross(u: NDArray, present: NDArray) -> NDArray:
    """Per epoch, the largest ``|u_i x u_j| = sqrt(1 - (u_i . u_j)^2)`` over present pairs."""
    i, j = np.triu_indices(u.shape[1], 1)
    dot = np.einsum("epk,epk->ep", u[:, i], u[:, j])
    cross_sq = np.where(present[:, i] & present[:, j], 1.0 - dot * dot, 0.0)
    return np.sqrt(np.clip(cross_sq.max(axis=1, initial=0.0), 0.0, None))


CHECKS: tuple[tuple[str, type[AttoptError] | None], ...] = (
    ("", None),
    ("NaN, inf or overflowing component in an observation vector", InvalidObservationError),
    ("zero-length observation vector", InvalidObservationError),
    ("weights must be finite and positive", InvalidObservationError),
    ("fewer than two vector observations", UnobservableError),
    ("body vectors are (anti)parallel: |b_i x b_j| < {tolerance:g}", UnobservableError),
    ("reference vectors are (anti)parallel: |r_i x r_j| < {tolerance:g}", UnobservableError),
)
"""The per-epoch checks in the order they are applied: ``(reason, exception)``; an epoch's
code is the index of the first it fails (0: none).  Shared by :func:`prepare_observations`
and the compiled solvers (:mod:`attopt.solvers.wahba.compiled`)."""
NONFINITE, ZERO_LENGTH, BAD_WEIGHT, TOO_FEW, BODY_PARALLEL, REFERENCE_PARALLEL = range(1, 7)


def check_outcomes(
    code: NDArray[np.intp], parallel_tolerance: float
) -> tuple[NDArray[np.object_], NDArray[np.object_]]:
    """Per epoch, the reason and exception class of its check ``code`` (:data:`CHECKS`)."""
    texts = np.empty(len(CHECKS), dtype=object)
    texts[:] = [text.format(tolerance=parallel_tolerance) for text, _ in CHECKS]
    errors = np.empty(len(CHECKS), dtype=object)
    errors[:] = [exc for _, exc in CHECKS]
    return texts[code], errors[code]


def prepare_observations(
    body: ArrayLike,
    reference: ArrayLike,
    weights: ArrayLike,
    present: ArrayLike | None = None,
    *,
    parallel_tolerance: float = PARALLEL_TOLERANCE,
) -> ObservationBatch:
    """Validate and normalise vector observations (one epoch ``(n, 3)`` or ``(N, n, 3)``)."""
    b, r, a, p = as_batch(body, reference, weights, present)
    n_epochs, n_obs = a.shape
    # Per epoch, the index of the first failed check in ``CHECKS`` (0: none).
    code = np.zeros(n_epochs, dtype=np.intp)

    def flag(mask: NDArray, check: int) -> None:
        code[mask & (code == 0)] = check

    with np.errstate(invalid="ignore", over="ignore"):
        nb = np.sqrt(np.einsum("eni,eni->en", b, b))
        nr = np.sqrt(np.einsum("eni,eni->en", r, r))
    # A norm is finite exactly when the components are, short of overflow
    # (components beyond ~1e154), which is reported with NaN and inf.
    finite = np.isfinite(nb) & np.isfinite(nr)
    flag(((~finite) & p).any(1), NONFINITE)
    short = (nb < MIN_NORM) | (nr < MIN_NORM)
    flag((short & finite & p).any(1), ZERO_LENGTH)
    with np.errstate(invalid="ignore"):
        bad_weight = ~(a > 0) | ~np.isfinite(a)
    flag((bad_weight & p).any(1), BAD_WEIGHT)
    flag(p.sum(1) < 2, TOO_FEW)

    ok = code == 0
    safe = p & ok[:, None]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        bu = b / nb[..., None]
        ru = r / nr[..., None]
    if not safe.all():
        bu = np.where(safe[..., None], bu, 0.0)
        ru = np.where(safe[..., None], ru, 0.0)
    flag(ok & (_max_pairwise_cross(bu, safe) < parallel_tolerance), BODY_PARALLEL)
    flag(ok & (_max_pairwise_cross(ru, safe) < parallel_tolerance), REFERENCE_PARALLEL)
    reason, error = check_outcomes(code, parallel_tolerance)

    valid = code == 0
    use = p & valid[:, None]
    if use.all():
        return ObservationBatch(bu, ru, a.copy(), valid, reason, error)
    # Absent observations get weight 0, invalid epochs a well-posed placeholder
    # (identity attitude) so that vectorised solvers stay finite; their results
    # are masked afterwards.
    placeholder = np.broadcast_to(_PLACEHOLDER[np.arange(n_obs) % 3], b.shape)
    body_out = np.where(use[..., None], bu, placeholder)
    ref_out = np.where(use[..., None], ru, placeholder)
    weights_out = np.where(use, a, 0.0)
    weights_out[~valid, : min(n_obs, 3)] = 1.0
    return ObservationBatch(body_out, ref_out, weights_out, valid, reason, error)
