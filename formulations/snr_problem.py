"""One epoch of the SNR attitude problem of Liu et al. 2023 (secs. 3.1-3.3), validated.

An epoch holds ``m`` received ADS-B messages: the measured SNR ``y_k`` (dB,
Liu et al. 2023 eq. 4), the unit line of sight ``l_k`` in the orbit frame (satellite
to aircraft, :func:`attopt.formulations.snr_model.line_of_sight`), the index of the
antenna that received it, the isotropic power ``10 lg P0_k`` (dBW, eq. 3) and
the noise power ``10 lg P_n`` (dBW, eq. 2).  The antennas' boresights in the
body frame and the gain pattern are inputs too: one pattern for every antenna,
or one per antenna (:class:`~attopt.formulations.gain_patterns.AntennaPatterns`).
The unknown is the attitude ``A = C_o^B`` (orbit -> body, ``docs/conventions.md``).

Batches are plain sequences of :class:`SnrEpoch` (epochs differ in ``m``); the
NLP solver pads each epoch to a bucket size itself
(:mod:`attopt.solvers.snr.padding`).

Policy on bad input (mirrors :mod:`attopt.formulations.vector_observations`):

* structurally malformed input (wrong shapes or dimensions, antenna index out
  of range, negative or non-integer antenna index) raises
  :class:`~attopt.formulations.errors.InvalidObservationError` when the
  :class:`SnrEpoch` is constructed;
* content problems are found by :func:`epoch_issue` and returned as an
  :class:`EpochIssue` (reason and exception class).  A single-epoch solve
  raises that exception, a sequence solve flags the epoch with the reason and
  carries on.  They are, in order:

  - :class:`InvalidObservationError`: a line of sight or boresight that is
    NaN/inf or zero; NaN/inf isotropic or noise power; a standard deviation
    that is not finite and positive; a measured SNR that is NaN/inf or below
    the reception threshold (Liu et al. 2023 sec. 5.1: 6 dB; such a message is not
    received, so its presence means a corrupted record);
  - :class:`UnobservableError`: fewer than three observations (three unknown
    angles; Liu et al. 2023 sec. 3.3 needs ``m_i >= 3`` per antenna, the one-step
    methods only three overall), or every observation received by antennas
    with (anti)parallel boresights, which leaves the rotation about that
    boresight unobservable (Liu et al. 2023 sec. 3.1, the symmetric gain pattern);
    for the two-step method (sec. 3.2) additionally fewer than two antennas
    with ``min_per_antenna`` observations each.

  An off-boresight angle beyond the pattern's main lobe *at some attitude* is
  not an input error: the attitude is the unknown.  :func:`content_issue`
  applies the first group alone (estimators of the pointing only, for which
  one antenna suffices: :mod:`attopt.solvers.geo.boresight`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import AttoptError, InvalidObservationError, UnobservableError
from attopt.formulations.gain_patterns import AntennaPatterns, GainPattern, shared_pattern
from attopt.formulations.link_budget import LinkBudget
from attopt.formulations.snr_model import SNR_SIGMA_DB

Array = NDArray[np.float64]

RECEPTION_THRESHOLD_DB = 6.0
"""Required SNR ``P_SNR^req`` of Liu et al. 2023 sec. 5.1 (dB)."""
PARALLEL_BORESIGHT_TOLERANCE = 1e-3
"""Boresights with ``|b_i x b_j|`` below this (about 0.057 deg) count as parallel."""
MIN_OBSERVATIONS = 3
"""Three unknown attitude angles need at least three SNRs (Liu et al. 2023 sec. 3.3)."""


def _readonly(x: ArrayLike, dtype: type = float) -> NDArray:
    a = np.array(x, dtype=dtype)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class SnrEpoch:
    """One epoch's SNR attitude problem (Liu et al. 2023 eqs. 4, 7, 18-19).

    Attributes:
        snr_db: ``(m,)`` measured SNRs ``y_k`` (dB).
        los_orbit: ``(m, 3)`` lines of sight satellite -> aircraft in the orbit
            frame (normalised by :attr:`unit_los`).
        antenna: ``(m,)`` index into ``boresights_body`` of the receiving antenna.
        boresights_body: ``(n_antennas, 3)`` antenna boresights in the body frame.
        p0_dbw: ``(m,)`` isotropic received power ``10 lg P0`` (dBW, eq. 3).
        noise_dbw: noise power ``10 lg(k_B T B)`` (dBW, eq. 2).
        pattern: the receive gain pattern (main lobe only): one for every antenna, or
            one per antenna (a sequence of ``n_antennas`` patterns or an
            :class:`~attopt.formulations.gain_patterns.AntennaPatterns`); patterns that
            are all equal are stored as that one pattern, so such an epoch is
            evaluated exactly as one with a single pattern.
        sigma_db: SNR standard deviation(s), scalar or ``(m,)`` (eq. 22's ``sigma_ij``).
        threshold_db: reception threshold; measured SNRs below it are rejected.
        transmitter: ``(m,)`` identifier of each observation's transmitter (the
            aircraft), or ``None``; the factor-graph smoother estimates one
            power offset per transmitter with it (``docs/smoother.md``).

    Arrays are stored as read-only float copies (``antenna`` as integers);
    instances compare and hash by identity.

    Example::

        >>> from attopt import CosinePowerPattern, LinkBudget, SnrEpoch
        >>> helix = CosinePowerPattern(peak_gain=14.46, exponent=6.0, min_gain_dbi=4.0)
        >>> epoch = SnrEpoch.from_ranges(
        ...     [12.0, 10.0, 9.0], [[0, 0, 1.0], [0.1, 0, 0.995], [0, 0.1, 0.995]], [0, 0, 0],
        ...     [[0.0, 0.0, 1.0]], [1.2e6, 1.5e6, 1.4e6], helix, LinkBudget(),
        ... )
        >>> epoch.m, epoch.n_antennas
        (3, 1)
    """

    snr_db: NDArray[np.float64]
    los_orbit: NDArray[np.float64]
    antenna: NDArray[np.intp]
    boresights_body: NDArray[np.float64]
    p0_dbw: NDArray[np.float64]
    noise_dbw: float
    pattern: GainPattern | AntennaPatterns | Sequence[GainPattern] = field(repr=False)
    sigma_db: NDArray[np.float64] | float = SNR_SIGMA_DB
    threshold_db: float = RECEPTION_THRESHOLD_DB
    transmitter: NDArray[np.intp] | None = None

    def __post_init__(self) -> None:
        try:
            y = _readonly(self.snr_db)
            los = _readonly(self.los_orbit)
            bores = _readonly(self.boresights_body)
            p0 = _readonly(self.p0_dbw)
            sigma = np.asarray(self.sigma_db, dtype=float)
            noise = float(self.noise_dbw)
            threshold = float(self.threshold_db)
        except (TypeError, ValueError) as exc:
            raise InvalidObservationError(f"SNR epoch arrays must be numeric: {exc}") from None
        raw_antenna = np.asarray(self.antenna)
        if y.ndim != 1:
            raise InvalidObservationError(f"snr_db must have shape (m,), got {y.shape}")
        m = y.shape[0]
        if los.shape != (m, 3):
            raise InvalidObservationError(f"los_orbit must have shape ({m}, 3), got {los.shape}")
        if p0.shape != (m,):
            raise InvalidObservationError(f"p0_dbw must have shape ({m},), got {p0.shape}")
        if bores.ndim != 2 or bores.shape[1] != 3 or bores.shape[0] < 1:
            raise InvalidObservationError(
                f"boresights_body must have shape (n_antennas, 3), got {bores.shape}"
            )
        if raw_antenna.shape != (m,) or (m and not np.issubdtype(raw_antenna.dtype, np.integer)):
            raise InvalidObservationError(
                f"antenna must be ({m},) integer indices, got {raw_antenna.shape} "
                f"{raw_antenna.dtype}"
            )
        antenna = _readonly(raw_antenna, np.intp)
        if m and (antenna.min() < 0 or antenna.max() >= bores.shape[0]):
            raise InvalidObservationError(
                f"antenna indices must lie in [0, {bores.shape[0]}), got {antenna.min()}.."
                f"{antenna.max()}"
            )
        if sigma.shape not in ((), (m,)):
            raise InvalidObservationError(f"sigma_db must be a scalar or ({m},), got {sigma.shape}")
        for name, value in (
            ("snr_db", y),
            ("los_orbit", los),
            ("antenna", antenna),
            ("boresights_body", bores),
            ("p0_dbw", p0),
            ("sigma_db", _readonly(np.broadcast_to(sigma, (m,)))),
        ):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "noise_dbw", noise)
        self._set_pattern(bores.shape[0])
        object.__setattr__(self, "threshold_db", threshold)
        if self.transmitter is not None:
            ids = np.asarray(self.transmitter)
            if ids.shape != (m,) or (m and not np.issubdtype(ids.dtype, np.integer)):
                raise InvalidObservationError(
                    f"transmitter must be ({m},) integer identifiers, got {ids.shape} {ids.dtype}"
                )
            object.__setattr__(self, "transmitter", _readonly(ids, np.intp))

    def _set_pattern(self, n_antennas: int) -> None:
        pattern = self.pattern
        if isinstance(pattern, AntennaPatterns):
            pattern = pattern.patterns
        if isinstance(pattern, Sequence):
            if len(pattern) != n_antennas:
                raise InvalidObservationError(
                    f"pattern must be one gain pattern or one per antenna ({n_antennas}), "
                    f"got {len(pattern)}"
                )
            object.__setattr__(self, "pattern", shared_pattern(pattern))

    @classmethod
    def from_ranges(
        cls,
        snr_db: ArrayLike,
        los_orbit: ArrayLike,
        antenna: ArrayLike,
        boresights_body: ArrayLike,
        range_m: ArrayLike,
        pattern: GainPattern | AntennaPatterns | Sequence[GainPattern],
        link_budget: LinkBudget | None = None,
        **kwargs: float | ArrayLike,
    ) -> SnrEpoch:
        """An epoch whose powers come from ``link_budget`` at slant ranges ``range_m``."""
        budget = LinkBudget() if link_budget is None else link_budget
        return cls(
            snr_db=snr_db,
            los_orbit=los_orbit,
            antenna=antenna,
            boresights_body=boresights_body,
            p0_dbw=budget.isotropic_power_dbw(range_m),
            noise_dbw=budget.noise_power_dbw,
            pattern=pattern,
            **kwargs,
        )

    @property
    def m(self) -> int:
        """Number of observations."""
        return int(self.snr_db.shape[0])

    def with_power_prior(self, mean_db: float, sigma_db: float) -> SnrEpoch:
        """The epoch with every transmitter's power known only in distribution, ``N(mean,
        sigma^2)`` dB and independent from row to row: ``10 lg P0 + mean`` and each row's
        sigma widened to ``sqrt(sigma_k^2 + sigma^2)``; the epoch itself for ``(0, 0)``."""
        if mean_db == 0.0 and sigma_db == 0.0:
            return self
        return replace(
            self, p0_dbw=self.p0_dbw + mean_db, sigma_db=np.hypot(self.sigma_db, sigma_db)
        )

    def take(self, rows: NDArray[np.intp] | NDArray[np.bool_]) -> SnrEpoch:
        """The epoch of the observations ``rows`` alone (indices or mask), e.g. without
        those of one transmitter."""
        return replace(
            self,
            snr_db=self.snr_db[rows],
            los_orbit=self.los_orbit[rows],
            antenna=self.antenna[rows],
            p0_dbw=self.p0_dbw[rows],
            sigma_db=np.asarray(self.sigma_db)[rows],
            transmitter=None if self.transmitter is None else self.transmitter[rows],
        )

    @property
    def n_antennas(self) -> int:
        return int(self.boresights_body.shape[0])

    def pattern_of(self, antenna: int) -> GainPattern:
        """The gain pattern of antenna ``antenna``."""
        if isinstance(self.pattern, AntennaPatterns):
            return self.pattern.patterns[antenna]
        return self.pattern

    @property
    def pattern_antenna(self) -> NDArray[np.intp] | None:
        """``(m,)`` receiving antenna of each observation when the antennas' patterns differ
        (the index that chooses each observation's pattern in the model), else ``None``."""
        return self.antenna if isinstance(self.pattern, AntennaPatterns) else None

    @cached_property
    def counts(self) -> NDArray[np.intp]:
        """Observations per antenna, ``(n_antennas,)``."""
        return np.bincount(self.antenna, minlength=self.n_antennas)

    @cached_property
    def unit_los(self) -> Array:
        """``(m, 3)`` unit lines of sight (NaN rows where the input is NaN or zero)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.los_orbit / np.linalg.norm(self.los_orbit, axis=1, keepdims=True)

    @cached_property
    def unit_boresights(self) -> Array:
        """``(n_antennas, 3)`` unit boresights in the body frame."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.boresights_body / np.linalg.norm(
                self.boresights_body, axis=1, keepdims=True
            )

    @property
    def boresight_rows(self) -> Array:
        """``(m, 3)`` unit boresight of the antenna that received each observation."""
        return self.unit_boresights[self.antenna]

    @property
    def weights(self) -> Array:
        """``(m,)`` ``1 / sigma_k^2``: the diagonal of ``C`` in Liu et al. 2023 eq. 22."""
        return np.asarray(self.sigma_db, dtype=float) ** -2


@dataclass(frozen=True)
class EpochIssue:
    """Why an epoch cannot be solved, and what a single-epoch call raises."""

    reason: str
    error: type[AttoptError]

    def raise_(self, method: str = "") -> None:
        raise self.error(f"{method}: {self.reason}" if method else self.reason)


def _finite_nonzero(vectors: Array) -> NDArray[np.bool_]:
    return np.isfinite(vectors).all(axis=-1) & np.any(vectors != 0, axis=-1)


def content_issue(problem: SnrEpoch) -> EpochIssue | None:
    """The first malformed value of the epoch (:class:`InvalidObservationError`)."""
    y = problem.snr_db
    checks = [
        (~_finite_nonzero(problem.los_orbit), "line of sight is NaN/inf or zero"),
        (
            ~_finite_nonzero(problem.boresights_body)[problem.antenna],
            "boresight of the receiving antenna is NaN/inf or zero",
        ),
        (~np.isfinite(problem.p0_dbw), "isotropic power is NaN/inf"),
        (
            np.full(problem.m, not np.isfinite(problem.noise_dbw)),
            "noise power is NaN/inf",
        ),
        (
            ~(np.isfinite(problem.sigma_db) & (problem.sigma_db > 0)),
            "SNR standard deviation must be finite and positive",
        ),
        (~np.isfinite(y), "measured SNR is NaN/inf"),
        (
            np.isfinite(y) & (y < problem.threshold_db),
            f"measured SNR below the {problem.threshold_db:g} dB reception threshold",
        ),
    ]
    for bad, text in checks:
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            return EpochIssue(
                f"{int(bad.sum())} invalid observation(s): {text} (first at index {first})",
                InvalidObservationError,
            )
    return None


def _spans_two_axes(boresights: Array) -> bool:
    """Whether some pair of the unit ``boresights`` is not (anti)parallel.

    ``|b_i x b_j|^2 = 1 - (b_i . b_j)^2`` for unit vectors.
    """
    cosines = boresights @ boresights.T
    cross_sq = 1.0 - cosines * cosines
    return bool(cross_sq.max(initial=0.0) >= PARALLEL_BORESIGHT_TOLERANCE**2)


def epoch_issue(problem: SnrEpoch, *, min_per_antenna: int | None = None) -> EpochIssue | None:
    """``None`` if the epoch is solvable, else the first issue (module docstring).

    ``min_per_antenna=None`` applies the one-step rule (NLSE/NLP, Liu et al. 2023
    sec. 3.3): at least :data:`MIN_OBSERVATIONS` observations overall, received
    by antennas whose boresights are not all (anti)parallel.  An integer
    applies the two-step rule (sec. 3.2): at least two non-parallel antennas
    with ``min_per_antenna`` observations or more each.
    """
    issue = content_issue(problem)
    if issue is not None:
        return issue
    if problem.m < MIN_OBSERVATIONS:
        return EpochIssue(
            f"{problem.m} observation(s): at least {MIN_OBSERVATIONS} are needed for three angles",
            UnobservableError,
        )
    counts = problem.counts
    if not _spans_two_axes(problem.unit_boresights[counts > 0]):
        return EpochIssue(
            "all observations come from antennas with (anti)parallel boresights: "
            "the rotation about the boresight is unobservable",
            UnobservableError,
        )
    if min_per_antenna is not None and not _spans_two_axes(
        problem.unit_boresights[counts >= min_per_antenna]
    ):
        return EpochIssue(
            f"the two-step method needs two non-parallel antennas with at least "
            f"{min_per_antenna} observations each; observations per antenna: "
            f"{counts.tolist()}",
            UnobservableError,
        )
    return None
