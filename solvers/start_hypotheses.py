"""Start hypotheses: has a filter started from a wide prior settled where the data say?

An extended Kalman filter linearises at its own estimate.  Started far from the truth (the
98 deg start of Yang et al. 2014), it can shrink its covariance along an axis the
measurements see only weakly while its error there stays large, and its innovations stay
consistent: with one station in view, a rotation about the line of sight changes no
innovation.  Measured in ``doa-ground`` (0 dB, L = 10, ``Q = 1e-12``): for 200 s the error
stays near 30 deg with a 1-sigma of 2-9 deg, while the normalised innovations average
0.8 per row.  No test on one filter's innovations can see this.

The check runs the same filter from the prior's attitude turned by each rotation of a
finite group (:func:`start_attitudes`: the prior's own start is the first), each with the
prior's covariance, and keeps each run's log-likelihood of its innovations,
``L_i(k) = sum_{j <= k} -(nu^T S^-1 nu + log det S + m log 2 pi) / 2`` (the
prediction-error decomposition; Schweppe 1965), the filter's ``log_likelihood``
diagnostic summed.  At each epoch :func:`start_verdict`:

* a run is *plausible* while ``2 (max_j L_j - L_i)`` stays within the chi-square quantile
  at ``1 - false_alarm`` with the start state's dimension as degrees of freedom (a
  likelihood-ratio test of the start);
* the reported run (the prior's own start) is flagged ``converging`` when a plausible
  run's attitude ``A_i`` is too far from it for its covariance ``P``: were ``A_i`` the
  truth's estimate, with an error of covariance ``P`` about the truth, the reported
  error would be shifted by ``d``, the rotation vector of ``A_0 A_i^-1``, and its NEES
  noncentral chi-square(3) with ``lambda = d^T P^-1 d``.  The epoch is flagged when that
  NEES would exceed the reports' integrity quantile (chi-square(3) at ``1 - 1e-4``,
  :data:`INTEGRITY_PROBABILITY`) with a probability above ``exceedance`` (default
  1e-3): ``lambda`` above :func:`largest_shift` (1.17).  The reported run's own
  likelihood does not matter: a run that started badly and has since joined the best
  one passes;
* after a failing stretch, the reported run counts as settled only once it has passed for
  a whole window of updates (``window``, the consistency test's,
  :func:`~attopt.solvers.sequential.converging_epochs`): runs that join each other do so
  with what their linearisation left them (measured on a noise-free 1,200 s pass from the
  paper's start: NEES 21-24 in the first six epochs that pass);
* and, for a filter that keeps its history
  (:attr:`~attopt.solvers.results.Track.history`), only once the disagreement it had at
  the last failing epoch ``k`` has died out in its own error dynamics
  (:func:`carried_epochs`): each plausible run's error-state difference ``d_i(k)`` is
  carried by the filter's closed-loop error transition ``M_j = P_j|j P_j|j-1^-1 Phi_j``
  (:func:`closed_loop_transitions`: the linear map of an error before epoch ``j``'s
  prediction onto the error after its update, since ``I - K_j H_j = P_j|j P_j|j-1^-1``),
  ``d_i(m) = M_m ... M_k+1 d_i(k)``, until it lies within the reported error state's
  covariance by the same shift, and the epochs are flagged up to the last at which its
  attitude part lies outside the attitude covariance.  The runs themselves join faster
  than that: the nonlinear filter draws every start onto the same estimate, so their
  agreement does not say that the truth's error has died out.  Measured in ``doa-ground``
  (``Q = 1e-9``, 0 dB, L = 1000, the paper's start): the runs agree from t = 231 s, when
  the error about the one station's line of sight is still 25 deg against a 1-sigma of 5
  deg (NEES 26); it falls to 4 deg by t = 400 s, and the carried differences keep the
  epochs flagged until t = 591 s (the EKF's largest valid NEES 26 -> 10, its RTS pass's 40
  -> 5, on an 800 s pass).

A second check needs no other start: an update that absorbs an outlier (a MUSIC DOA from
an ambiguous peak) moves the estimate by more than its covariance then says, and no later
innovation shows it (measured at 0 dB, L = 1: 0.8-1.1 % of the settled epochs beyond the
integrity quantile; gating the outliers, none).  The same filter with Huber-weighted
updates (``robust``, :func:`~attopt.solvers.filters.common.robust_noise`) runs from the
prior's start, and the reported run is flagged ``inconsistent`` where that run lies
outside its covariance by the same shift.

The flags change no estimate (:func:`unchecked` gives the run without them).  A run that
raises (a diverging rate) explains nothing and is left out.  A smoother over the runs
(``whole_pass``) judges plausibility on the whole pass's likelihood at every epoch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, ncx2

from attopt.formulations.errors import ModelMismatchError
from attopt.solvers.results import Track, attitude_errors, normalised_errors
from attopt.solvers.sequential import FilterHistory, converging_epochs

Array = NDArray[np.float64]

GROUPS = ("none", "T", "O", "I")
"""The start hypotheses: the rotations of scipy's ``create_group`` (``"T"`` tetrahedral, 12;
``"O"`` octahedral, 24; ``"I"`` icosahedral, 60: within 90, 62.8 and 44.5 deg of every
attitude), or ``"none"``: the prior's start alone, no check."""
INTEGRITY_PROBABILITY = 1e-4
"""The tail probability of the NEES quantile the reports count epochs beyond."""
EXCEEDANCE = 1e-3
"""Default largest probability, for an epoch the check passes, that the reported NEES
would exceed the integrity quantile were a plausible start's estimate the truth's."""
OUTSIDE = "outside this estimate's covariance"
AMBIGUOUS = f"converging: a start hypothesis that explains the measurements as well lies {OUTSIDE}"
"""The reason of an epoch a plausible start's run fails."""
PULLED = f"inconsistent: the run with Huber-weighted updates lies {OUTSIDE}"
"""The reason of an epoch the robust run fails (an outlier the Gaussian update absorbed)."""
SETTLING = "converging: fewer than {window} updates since another run last lay " + OUTSIDE
"""The reason of an epoch within ``window`` updates after the last it failed."""
CARRIED = (
    "converging: a run's difference from the last epoch it lay outside, carried by this "
    "filter's error dynamics, still lies " + OUTSIDE
)
"""The reason of an epoch before the differences of the last it failed have died out in the
filter's error dynamics (:func:`carried_epochs`)."""


@lru_cache(maxsize=3)
def rotation_group(name: str) -> Rotation:
    """The rotations of group ``name`` (``"T"``, ``"O"`` or ``"I"``, :data:`GROUPS`), in
    scipy's order."""
    return Rotation.create_group(name)


def start_attitudes(attitude: Rotation, group: str) -> Rotation:
    """The start attitudes ``G_i A``: the prior's ``attitude`` turned in the body frame by
    each rotation of ``group`` (:data:`GROUPS`), the prior's own first.

    Example::

        >>> from scipy.spatial.transform import Rotation
        >>> from attopt.solvers.start_hypotheses import start_attitudes
        >>> prior = Rotation.from_euler("z", 98, degrees=True)
        >>> starts = start_attitudes(prior, "O")
        >>> len(starts), bool(starts[0].approx_equal(prior))
        (24, True)
    """
    if group not in GROUPS:
        raise ValueError(f"start hypotheses must be one of {GROUPS}, not {group!r}")
    if group == "none":
        return Rotation.concatenate([attitude])
    turns = rotation_group(group)
    identity = int(np.argmin(turns.magnitude()))
    return turns[[identity, *(i for i in range(len(turns)) if i != identity)]] * attitude


def largest_shift(exceedance: float = EXCEEDANCE) -> float:
    """The noncentrality ``lambda`` at which a chi-square(3) NEES exceeds the integrity
    quantile with probability ``exceedance`` (module docstring).

    Example::

        >>> from attopt.solvers.start_hypotheses import largest_shift
        >>> round(largest_shift(1e-3), 2)
        1.17
    """
    quantile = chi2.isf(INTEGRITY_PROBABILITY, 3)
    if not INTEGRITY_PROBABILITY < exceedance < 1.0:
        raise ValueError(f"exceedance must lie in ({INTEGRITY_PROBABILITY:g}, 1)")
    return float(brentq(lambda shift: ncx2.sf(quantile, 3, shift) - exceedance, 0.0, 1e3))


def _plausible(runs: Sequence[Track], false_alarm: float, whole_pass: bool) -> NDArray[np.bool_]:
    """``(runs, N)``: whether each run's cumulative innovation log-likelihood (the whole
    pass's at every epoch with ``whole_pass``) is within half the chi-square quantile, at
    ``1 - false_alarm`` with the start state's dimension, of the best run's."""
    likelihood = np.array(
        [np.cumsum(np.nan_to_num(run.diagnostics["log_likelihood"])) for run in runs]
    )
    if whole_pass:
        likelihood[:] = likelihood[:, -1:]
    threshold = 0.5 * chi2.isf(false_alarm, runs[0].state_covariance.shape[-1])
    return likelihood >= np.max(likelihood, axis=0) - threshold


def start_verdict(
    runs: Sequence[Track],
    false_alarm: float,
    exceedance: float = EXCEEDANCE,
    whole_pass: bool = False,
    robust: Track | None = None,
) -> NDArray[np.object_]:
    """Per epoch, why the first of ``runs`` fails the check (module docstring), or ``""``.

    ``runs`` are one filter's tracks on one pass, from each start, each with the
    ``log_likelihood`` diagnostic; a run whose track is invalid at an epoch is compared
    with nothing there (its likelihood still counts).  ``whole_pass``: plausibility from
    the whole pass's likelihood at every epoch (smoothed runs).  ``robust``: the run with
    Huber-weighted updates from the same start, compared at every epoch.
    """
    return _verdict(runs, _plausible(runs, false_alarm, whole_pass), exceedance, robust)


def _verdict(
    runs: Sequence[Track], plausible: NDArray[np.bool_], exceedance: float, robust: Track | None
) -> NDArray[np.object_]:
    """:func:`start_verdict` with the runs' plausibility ``plausible`` (:func:`_plausible`)."""
    reported = runs[0]
    reason = np.full(len(reported), "", dtype=object)
    compared = [(run, keep, AMBIGUOUS) for run, keep in zip(runs[1:], plausible[1:], strict=True)]
    if robust is not None:
        compared.append((robust, np.ones(len(reported), dtype=bool), PULLED))
    limit = largest_shift(exceedance)
    for run, keep, why in compared:
        rows = np.flatnonzero(keep & run.valid & reported.valid & (reason == ""))
        if not rows.size:
            continue
        difference = attitude_errors(
            reported.quaternion[rows], Rotation.from_quat(run.quaternion[rows])
        )
        nees = normalised_errors(difference, reported.covariance[rows])
        reason[rows[nees > limit]] = why
    return reason


def closed_loop_transitions(history: FilterHistory) -> Array:
    """``(N, s, s)``: the filter's error transition through each epoch's prediction and
    update, ``M_j = P_j|j P_j|j-1^-1 Phi_j`` (``I - K_j H_j = P_j|j P_j|j-1^-1`` for the
    Kalman gain; ``M_j = Phi_j`` at an epoch without an update), NaN where the history is
    not finite.

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.sequential import FilterHistory
        >>> from attopt.solvers.start_hypotheses import closed_loop_transitions
        >>> predicted, filtered = 4.0 * np.eye(6)[None], np.eye(6)[None]
        >>> history = FilterHistory(None, None, predicted, np.eye(6)[None], None, None, filtered)
        >>> float(closed_loop_transitions(history)[0, 0, 0])
        0.25
    """
    predicted = np.asarray(history.predicted_covariance, dtype=float)
    filtered = np.asarray(history.filtered_covariance, dtype=float)
    transition = np.asarray(history.transition, dtype=float)
    finite = (
        np.isfinite(predicted).all(axis=(1, 2))
        & np.isfinite(filtered).all(axis=(1, 2))
        & np.isfinite(transition).all(axis=(1, 2))
    )
    result = np.full(predicted.shape, np.nan)
    try:  # P_f P_p^-1 = (P_p^-1 P_f)^T for the symmetric covariances
        gain = np.swapaxes(np.linalg.solve(predicted[finite], filtered[finite]), 1, 2)
    except np.linalg.LinAlgError:  # a singular prediction (no process noise, a zero prior)
        gain = filtered[finite] @ np.linalg.pinv(predicted[finite], hermitian=True)
    result[finite] = gain @ transition[finite]
    return result


def carried_epochs(
    covariance: Array,
    attitude: slice,
    differences: Mapping[int, Array],
    limit: float,
    transitions: Array,
) -> NDArray[np.bool_]:
    """The epochs from each of ``differences``' epoch to the last at which, carried by the
    reported run's closed-loop ``transitions`` (``(N, s, s)``,
    :func:`closed_loop_transitions` of its history; module docstring), it lies outside the
    reported attitude covariance (the ``attitude`` block of the error-state
    ``covariance``, ``(N, s, s)``).

    ``differences`` maps an epoch ``k`` to ``(s, r)`` error states at ``k`` of other runs
    relative to the reported run's.  Each is carried from ``k`` while its noncentrality in
    the whole error state, ``d^T P^-1 d``, exceeds ``limit`` (:func:`largest_shift`): the
    whole state's bounds the attitude block's, which can pass through zero while the
    difference lives on in the rate or bias and turns back into attitude (measured in
    ``doa-ground``: the attitude block's alone falls within the limit at t = 305-325 s and
    is back at 27 by t = 430 s).  The epochs flagged run from ``k`` to the last at which the
    attitude block's noncentrality ``d_a^T P_a^-1 d_a`` exceeds ``limit`` (none when it
    never does), through any passage within it.  The carrying of all of them stops at an
    epoch with a non-finite transition or covariance (the filter's track ends there).

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.start_hypotheses import carried_epochs
        >>> unit, halving = np.tile(np.eye(3), (6, 1, 1)), np.tile(0.5 * np.eye(3), (6, 1, 1))
        >>> difference = {0: np.array([[4.0], [0.0], [0.0]])}  # halved: 2, 1, 0.5, ...
        >>> carried_epochs(unit, slice(0, 3), difference, 1.17, halving).tolist()
        [False, True, False, False, False, False]
    """
    n = len(covariance)
    flagged = np.zeros(n, dtype=bool)
    pending = dict(differences)
    size = transitions.shape[-1]
    carried, origin, reach = np.zeros((size, 0)), np.zeros(0, dtype=int), np.zeros(0, dtype=int)

    def settle(keep: NDArray[np.bool_]) -> None:
        """Flag the reach of the columns not kept, and keep the others."""
        nonlocal carried, origin, reach
        for start, stop in zip(origin[~keep], reach[~keep], strict=True):
            flagged[start + 1 : stop + 1] = True
        carried, origin, reach = carried[:, keep], origin[keep], reach[keep]

    m = min(pending, default=n)
    while m < n - 1:
        if m in pending:
            added = pending.pop(m)
            carried = np.hstack([carried, added])
            origin = np.r_[origin, np.full(added.shape[1], m)]
            reach = np.r_[reach, np.full(added.shape[1], m)]
        if not carried.shape[1]:
            if not pending:
                break
            m = min(pending)
            continue
        m += 1
        carried = transitions[m] @ carried
        if not (np.isfinite(carried).all() and np.isfinite(covariance[m]).all()):
            settle(np.zeros(carried.shape[1], dtype=bool))
            continue
        error = carried[attitude]
        block = covariance[m][attitude, attitude]
        outside = np.einsum("ir,ir->r", error, np.linalg.solve(block, error)) > limit
        reach[outside] = m
        settle(np.einsum("ir,ir->r", carried, np.linalg.solve(covariance[m], carried)) > limit)
    settle(np.zeros(carried.shape[1], dtype=bool))
    return flagged


def _differences(reported: Track, runs: Sequence[Track], k: int) -> Array:
    """``(s, r)``: the error states at epoch ``k`` of ``runs`` relative to ``reported``'s
    (attitude: :func:`~attopt.solvers.results.attitude_errors`; the other block: the
    difference), in ``reported``'s state order."""
    other = next(name for name in reported.state if name != "attitude")
    differences = np.zeros((reported.state_covariance.shape[-1], len(runs)))
    quaternions = np.array([run.quaternion[k] for run in runs])
    differences[reported.block("attitude")] = attitude_errors(
        quaternions, Rotation.from_quat(np.tile(reported.quaternion[k], (len(runs), 1)))
    ).T
    differences[reported.block(other)] = np.array(
        [getattr(run, other)[k] - getattr(reported, other)[k] for run in runs]
    ).T
    return differences


@dataclass(frozen=True)
class StartCheck:
    """A filter's runs from its start hypotheses, kept in the checked track's ``report``.

    Attributes:
        runs: one track per start that ran to the end (:func:`start_attitudes` order, the
            prior's own start first), none of them flagged by the check.
        false_alarm: the plausibility test's false-alarm probability.
        window: updates the check must pass for, after failing, before an epoch counts.
        diverged: starts whose run raised (a diverging rate), left out.
        exceedance: the agreement test's (:func:`largest_shift`).
        robust: the run from the prior's start with Huber-weighted updates, if any.
    """

    runs: tuple[Track, ...]
    false_alarm: float
    window: int
    exceedance: float = EXCEEDANCE
    diverged: int = 0
    robust: Track | None = None

    def plausible(self) -> tuple[Track, ...]:
        """The runs plausible over the whole pass (the first always kept)."""
        keep = _plausible(self.runs, self.false_alarm, whole_pass=True)[:, -1]
        keep[0] = True
        return tuple(run for run, k in zip(self.runs, keep, strict=True) if k)


def checked(check: StartCheck, whole_pass: bool = False, reported: Track | None = None) -> Track:
    """``reported`` (default: the first of ``check.runs``) flagged where
    :func:`start_verdict` fails it against the other runs, with ``check`` as its
    ``report`` (unchanged when there is one run).

    ``whole_pass``: judge plausibility on the whole pass's likelihood at every epoch (a
    smoother's runs, each of whose estimates uses every measurement).
    """
    reported = check.runs[0] if reported is None else reported
    if len(check.runs) == 1 and check.robust is None:
        return reported
    runs = (reported, *check.runs[1:])
    plausible = _plausible(runs, check.false_alarm, whole_pass)
    reason = _verdict(runs, plausible, check.exceedance, check.robust)
    failed = reason != ""
    last = np.append(failed[:-1] & ~failed[1:], False)
    settling = converging_epochs(
        reported.diagnostics["nis"], reported.diagnostics["nis_dof"], last, check.window
    )
    carried = _carried(reported, runs, plausible, check.exceedance, np.flatnonzero(last))
    flagged = reported.flagged(reason == AMBIGUOUS, AMBIGUOUS)
    flagged = flagged.flagged(reason == PULLED, PULLED, ModelMismatchError)
    flagged = flagged.flagged(settling, SETTLING.format(window=check.window))
    flagged = flagged.flagged(carried, CARRIED)
    return replace(flagged, report=check)


def _carried(
    reported: Track,
    runs: Sequence[Track],
    plausible: NDArray[np.bool_],
    exceedance: float,
    last_failures: NDArray[np.intp],
) -> NDArray[np.bool_]:
    """:func:`carried_epochs` from the differences, at the last epoch of each failing
    stretch (``last_failures``), of the runs ``plausible`` and valid there; none for a
    track without a history."""
    if reported.history is None or not last_failures.size:
        return np.zeros(len(reported), dtype=bool)
    differences = {}
    for k in last_failures:
        keep = plausible[1:, k]
        compared = [run for run, kept in zip(runs[1:], keep, strict=True) if kept and run.valid[k]]
        if compared:
            differences[int(k)] = _differences(reported, compared, k)
    return carried_epochs(
        reported.state_covariance,
        reported.block("attitude"),
        differences,
        largest_shift(exceedance),
        closed_loop_transitions(reported.history),
    )


def unchecked(track: Track) -> Track:
    """The run the start check flagged ``track`` from (``track`` itself when unchecked): a
    start for another estimator, or the estimates behind a convergence figure, never a
    result.

    Example::

        >>> import numpy as np
        >>> from attopt import Snapshot, estimator
        >>> from attopt.solvers.start_hypotheses import unchecked
        >>> vectors = np.eye(3)[:2]
        >>> snapshot = Snapshot.from_vectors(vectors, vectors, 1e-3)
        >>> track = estimator("quest").solve_sequence([snapshot])
        >>> unchecked(track) is track
        True
    """
    return track.report.runs[0] if isinstance(track.report, StartCheck) else track


def flagged_by_start_check(reason: ArrayLike) -> NDArray[np.bool_]:
    """Which of the epochs' ``reason`` are the check's (:data:`AMBIGUOUS`, :data:`PULLED`,
    :data:`SETTLING`, :data:`CARRIED`): their estimates exist (the unchecked run's) but are
    not confirmed.

    Example::

        >>> from attopt.solvers.start_hypotheses import AMBIGUOUS, flagged_by_start_check
        >>> flagged_by_start_check([AMBIGUOUS, "", "lost track"]).tolist()
        [True, False, False]
    """
    return np.char.endswith(np.asarray(reason, dtype=str), OUTSIDE)
