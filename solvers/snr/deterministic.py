"""Deterministic two-step method of Liu et al. 2023 sec. 3.2 (boresights, then QUEST).

Step 1, per antenna with enough observations: invert the gain pattern for
each SNR to get ``cos(alpha_k)`` (Liu et al. 2023 eqs. 4, 63;
:mod:`attopt.solvers.snr.pattern_inverse`) and fit the antenna's boresight in the
orbit frame, ``{b_i}_o``, to the cones ``l_k . b = cos(alpha_k)`` (eq. 15) by
least squares on the unit sphere (:mod:`attopt.solvers.snr.boresight`).

Step 2: Wahba's problem (eqs. 16-17) with the pairs
``({b_i}_B, {b_i}_o)`` (body = mounting direction, reference = estimate),
solved by QUEST (:data:`attopt.solvers.wahba.QUEST`, as in Liu et al. 2023
sec. 5.1).  QUEST's weights are ``a_i = 1 / sigma_i^2`` with ``sigma_i^2`` the
mean tangent-plane variance of the estimated boresight, whose covariance
comes from the SNR noise through step 1; the returned covariance is QUEST's
``[sum_i a_i (I - b_i b_i^T)]^-1`` (Cilden Guler et al. 2017 eq. 32).  QUEST's measurement
model has isotropic direction noise; the boresight estimates' is not (it is
elongated along the narrower spread of their lines of sight), so the
covariance is an approximation: in the Monte Carlo test of
``tests/test_snr_solvers.py`` (40 observations) its trace was 0.93 of the
scatter's, which the test holds to within 25%.
The reported ``loss`` is the SNR loss (eq. 19) of the two-step attitude, so
all SNR solvers are scored alike; Wahba's loss (eq. 17) is a diagnostic.

Observations.  Liu et al. 2023 sec. 3.3 requires ``m_i >= 3`` per antenna; with the
default ``min_per_antenna = 3`` an antenna with fewer is not used and the
epoch is flagged (:class:`~attopt.formulations.errors.UnobservableError`) unless two
non-parallel antennas remain.  ``min_per_antenna = 2`` also uses antennas with
two observations: the two cones meet in two lines, a two-fold ambiguity
resolved by the candidate closer to the a-priori boresight direction
``A_prior^T {b_i}_B`` (``A_prior`` the prior attitude, by default the nominal
Earth-pointing attitude, body = orbit frame) and counted in the diagnostics
(``two_fold_antennas``; ``two_fold_margin_deg`` is the smallest difference of
the two candidates' angles to the prior, small when the choice is fragile).
Noise-free, with three or more observations on each antenna whose lines of
sight are not coplanar, the method is exact.

Ambiguous cones.  With few observations (three, nearly coplanar lines of sight)
an antenna's cones can be fitted almost as well by a second boresight direction
tens of degrees away (:mod:`attopt.solvers.snr.boresight`, Second minimum); the
linearised covariance then describes only the basin that noise made global.  An
antenna whose second minimum lies within
:data:`~attopt.solvers.snr.boresight.AMBIGUITY_GATE` of the global one (in the
fit's chi-square units) is not used, as if it had too few observations, and
counted in ``ambiguous_antennas`` (``second_minimum_gap`` is the smallest such
gap): without two determined antennas the epoch is flagged
(:class:`~attopt.formulations.errors.UnobservableError`) rather than reported
with an error many times its sigma.  The exact two-fold case of two
observations keeps the prior's choice above.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import AttoptError, ConvergenceError, UnobservableError
from attopt.formulations.snr_problem import EpochIssue, SnrEpoch, epoch_issue
from attopt.solvers.snapshot_sequence import EpochEstimate
from attopt.solvers.snr.boresight import BoresightEstimate, estimate_boresight
from attopt.solvers.snr.driver import SnrSolver
from attopt.solvers.snr.exclusion import EXCLUSION_DIAGNOSTICS
from attopt.solvers.snr.fit import SELECTION_BIAS_DIAGNOSTICS, fit_at
from attopt.solvers.snr.pattern_inverse import cos_from_gain
from attopt.solvers.wahba import QUEST

Array = NDArray[np.float64]

LIU2023_MIN_PER_ANTENNA = 3
"""``m_i >= 3`` of Liu et al. 2023 sec. 3.3."""
NOMINAL_ATTITUDE = Rotation.identity()
"""Earth pointing: body frame = orbit frame (``docs/conventions.md``)."""

DETERMINISTIC_DIAGNOSTICS = (
    "antennas_used",
    "two_fold_antennas",
    "two_fold_margin_deg",
    "ambiguous_antennas",
    "second_minimum_gap",
    "clamped_cos",
    "wahba_loss",
    "quest_iterations",
    "outside_lobe",
    *EXCLUSION_DIAGNOSTICS,
    *SELECTION_BIAS_DIAGNOSTICS,
)


@dataclass(frozen=True)
class TwoStep:
    """Result of :func:`two_step` (``attitude`` is None unless ``valid``)."""

    attitude: Rotation | None
    covariance: Array
    diagnostics: dict[str, float]
    reason: str = ""
    error: type[AttoptError] = ConvergenceError
    boresights: tuple[BoresightEstimate, ...] = field(default=(), repr=False)

    @property
    def valid(self) -> bool:
        return self.attitude is not None


def _antenna_boresight(
    problem: SnrEpoch, antenna: int, prior: Rotation
) -> tuple[BoresightEstimate, int]:
    rows = problem.antenna == antenna
    gain = problem.snr_db[rows] - problem.p0_dbw[rows] + problem.noise_dbw  # Liu et al. 2023 eq. 4
    cos_alpha, dcos_dgain, clamped = cos_from_gain(problem.pattern_of(antenna), gain)
    sigma_cos = np.abs(dcos_dgain) * problem.sigma_db[rows]
    prior_direction = prior.inv().apply(problem.unit_boresights[antenna])
    estimate = estimate_boresight(problem.unit_los[rows], cos_alpha, sigma_cos, prior_direction)
    return estimate, clamped


def two_step(
    problem: SnrEpoch,
    prior: Rotation | None = None,
    min_per_antenna: int = LIU2023_MIN_PER_ANTENNA,
) -> TwoStep:
    """Liu et al. 2023 sec. 3.2 on a validated epoch (see the module docstring)."""
    prior = NOMINAL_ATTITUDE if prior is None else prior
    antennas = np.flatnonzero(problem.counts >= max(min_per_antenna, 2))
    diagnostics = dict.fromkeys(DETERMINISTIC_DIAGNOSTICS, np.nan)
    estimates, clamped = [], 0
    for antenna in antennas:
        estimate, n_clamped = _antenna_boresight(problem, int(antenna), prior)
        estimates.append(estimate)
        clamped += n_clamped
    two_fold = [e.two_fold_margin for e in estimates if e.two_fold]
    ambiguous = np.array([e.ambiguous for e in estimates], dtype=bool)
    gaps = [e.second_minimum_gap for e, a in zip(estimates, ambiguous, strict=True) if a]
    diagnostics.update(
        antennas_used=float(len(estimates) - ambiguous.sum()),
        two_fold_antennas=float(len(two_fold)),
        two_fold_margin_deg=float(np.degrees(min(two_fold))) if two_fold else np.nan,
        ambiguous_antennas=float(ambiguous.sum()),
        second_minimum_gap=min(gaps) if gaps else np.nan,
        clamped_cos=float(clamped),
    )
    variance = np.array([e.variance for e in estimates])
    usable = np.isfinite(variance) & (variance > 0) & ~ambiguous
    if usable.sum() < 2:
        return TwoStep(
            None,
            np.full((3, 3), np.nan),
            diagnostics,
            "fewer than two antennas with a determined boresight direction: "
            f"variances {np.array2string(variance, precision=3)} rad^2"
            + "".join(
                f"; antenna {int(a)}, a second direction "
                f"{np.degrees(e.second_minimum_angle):.0f} deg away fits its cones "
                f"within a cost of {e.second_minimum_gap:.1f}"
                for a, e, amb in zip(antennas, estimates, ambiguous, strict=True)
                if amb
            ),
            UnobservableError,
            tuple(estimates),
        )
    body = problem.unit_boresights[antennas[usable]]
    reference = np.stack([e.direction for e, ok in zip(estimates, usable, strict=True) if ok])
    try:
        wahba = QUEST.solve_vectors(body, reference, 1.0 / variance[usable])
    except AttoptError as exc:
        return TwoStep(
            None, np.full((3, 3), np.nan), diagnostics, f"QUEST: {exc}", type(exc), tuple(estimates)
        )
    diagnostics.update(
        wahba_loss=wahba.loss, quest_iterations=float(wahba.diagnostics["iterations"])
    )
    return TwoStep(wahba.attitude, wahba.covariance, diagnostics, boresights=tuple(estimates))


@dataclass(frozen=True, repr=False)
class DeterministicSolver(SnrSolver):
    """Registry entry ``"deterministic"``: :func:`two_step` per epoch.

    The a-priori attitude (``prior``, or the previous epoch's estimate in a
    sequence) only resolves two-fold ambiguities (``min_per_antenna = 2``).
    """

    min_per_antenna: int = LIU2023_MIN_PER_ANTENNA
    name: str = "deterministic"
    description: str = (
        "two-step: pattern inverse, boresight cones, QUEST (Liu et al. 2023 sec. 3.2)"
    )
    diagnostic_names: ClassVar[tuple[str, ...]] = DETERMINISTIC_DIAGNOSTICS

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_per_antenna < 2:
            raise ValueError("a boresight needs at least two cones (min_per_antenna >= 2)")

    def issue(self, problem: SnrEpoch) -> EpochIssue | None:
        """The two-step rule: two non-parallel antennas with ``min_per_antenna`` observations."""
        return epoch_issue(problem, min_per_antenna=self.min_per_antenna)

    def attitude_shifts(
        self, problem: SnrEpoch, estimate: EpochEstimate, errors: Array, jacobian: Array
    ) -> Array:
        """The attitude errors that SNR errors cause through the two-step method's own
        gain: for each row ``e`` of ``errors``, the attitude error of the estimate against
        :func:`two_step` on the SNRs less ``e``, its two-fold choices made at the estimate.
        The pattern inverse, the boresight cones and QUEST respond to an SNR bias otherwise
        than the least squares' eq. 22 gain, which under-covers this method's bias
        (``docs/integrity.md``); where ``e`` is not finite (a message the estimate does
        not predict) or the re-solve fails, that gain is used."""
        shifts = []
        for e in np.atleast_2d(errors):
            result = None
            if np.all(np.isfinite(e)):
                shifted = replace(problem, snr_db=problem.snr_db - e)
                result = two_step(shifted, estimate.attitude, self.min_per_antenna)
            if result is not None and result.valid:
                shifts.append(attitude_error(estimate.attitude, result.attitude))
            else:
                shifts.append(super().attitude_shifts(problem, estimate, e, jacobian)[0])
        return np.array(shifts)

    def estimate_epoch(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        result = two_step(problem, prior, self.min_per_antenna)
        if not result.valid:
            return EpochEstimate.failed(result.reason, result.diagnostics, result.error)
        fit = fit_at(problem, result.attitude)
        diagnostics = {**result.diagnostics, "outside_lobe": float(fit.outside_lobe)}
        return EpochEstimate(result.attitude, result.covariance, fit.loss, diagnostics)
