"""Start and re-acquisition of the gyro filters from a single-frame solution.

The MEKF and USQUE (:mod:`attopt.solvers.filters.estimators`) run through
:func:`attopt.solvers.sequential.run_filter` with a :class:`SingleFrameRecovery`:

* **Start without a prior** (``Pass.prior is None``): the filter propagates
  from the first gyro sample with an unknown attitude (``sigma = pi`` per
  axis, so its epochs are flagged "attitude not determined") and zero bias
  with the gyro model's initial bias sigma; at the first epoch whose
  measurement has a :func:`single_frame` solution, the attitude and its
  covariance are set to it.
* **Start against a prior** (``recovery = "restart"``): at the first epoch with
  a measurement, the predicted attitude is compared with that epoch's
  single-frame solution; if they contradict each other (:func:`contradicts`),
  the filter starts from the single frame.  Otherwise the single frame is that
  epoch's update, as a direct observation of the attitude (:func:`fuse`: ``H =
  [I 0]``, ``R`` its covariance) in place of the filter's own update of the
  measurement, which would be linearised at the prior.  A prior far off, even
  one inside its own covariance, can otherwise put the first update into a
  second basin of the MAP cost and keep it there while every SNR is accepted
  (Markley and Crassidis 2014 sec. 6.2 on the MEKF's small-error assumption;
  measured in ``adsb-sky``'s quick run: a 29 deg prior error against 10 deg
  sigmas left the MEKF 20-99 deg off for 240 s, NEES up to 35).  When that epoch has no
  single frame (a measurement that does not determine every axis, or one whose residuals
  fail their test), the filter goes on from the prior unconfirmed; if its update there
  rejects at least as many observations as it uses (:func:`~attopt.solvers.sequential.
  rejected_epoch`), the measurements contradict the prior, and the filter waits for a
  single frame as from a wide prior (below; :meth:`SingleFrameRecovery.after_update`).
  Measured in ``adsb-sky``'s quick run under the real sky: USQUE's first epoch was
  reported valid 40 deg off (NEES 40), its update using 1 of 87 SNRs (84 unpredictable at
  the prior's attitude, 2 gated); and on a test pass with one vector per epoch for 60 s
  and a prior 70-80 deg off (10 deg sigmas), flagging only the window of updates after
  that epoch left 33-34 later epochs valid beyond the integrity quantile.
* **Start against a wide prior** (an attitude sigma above ``max_attitude_sigma``: the
  prior does not determine the attitude): when the first measurement epoch has no single
  frame, the check waits for the first epoch whose measurement alone determines every axis
  (:func:`determines`), and the epochs until then are flagged ``converging``
  (:attr:`SingleFrameRecovery.pending`), however small the filter's covariance has
  become: its updates were linearised far from the truth, and where they see only two
  axes (one unit vector) the covariance of the third shrinks through the dynamics while
  its error stays.  Measured in ``doa-ground`` (the 98 deg start
  of Yang et al. 2014 with 60 deg sigmas, one station in view): the MEKF was reported valid
  7-18 deg off at sigmas of 0.1-6 deg (NEES up to 35) until a second station came into
  view; with the wait, its converging rows' share beyond the integrity quantile fell from
  0.43-0.53 to 0 (valid 0.89-0.92 -> 0.40-0.41).  The epoch that ends the wait restarts
  the filter from its single frame, as a re-acquisition does (below), whether or not the
  two contradict each other: the bias estimate, learnt from those updates, is kept with
  the filter's bias covariance plus the prior's.  Fused instead, the frame corrected the
  attitude but left the bias estimate and its shrunken covariance: measured in
  ``doa-ground`` at 0 dB with one snapshot and at -14 dB, the MEKF was then valid 1-2 deg
  off at sigmas near 0.3 deg (NEES up to 63) for 200-700 s in two passes of four; restarted,
  none of the 35,000 valid epochs of those two passes is beyond the quantile.
* **Re-acquisition** (``recovery = "restart"``): at every measurement epoch of
  a track the :class:`~attopt.solvers.sequential.TrackMonitor` finds lost, and
  when it finds the consistency window failing for ``max_rejected_epochs``
  consecutive updates (if the single frame contradicts the estimate), the
  attitude restarts from the single frame of that epoch's measurement.  While
  the single frame fails its residual test (outliers), the next epoch tries
  again with the covariance left as it is: an inflated covariance would let
  the filter accept the first clean epoch from wherever it has drifted to
  (measured in a 20 dB outlier burst: accepted 73 deg off, NEES 599).  Where
  the measurement cannot determine the attitude at all, the lost track falls
  back to the covariance inflation (every ``max_rejected_epochs`` rejected
  epochs).

A re-acquisition keeps the bias estimate and adds the prior's bias covariance (the gyro
model's initial bias sigma without a prior) to the filter's, as the lost-track inflation
does, with no attitude-bias correlation: the updates that lost the track, or were made
against a wrong attitude, also corrupted the bias, and its covariance then claims a
precision the estimate does not have (``docs/filters.md``, Faults: the lost-track
measurement in ``doa-ground``); the bias is re-learnt from the following updates.  The
filter's own covariance is kept in the sum because it may have grown beyond the prior's
(a gyro-only stretch): reset to the prior's, the MEKF leaving the ``wahba-mag-sun`` eclipse
with Liu et al. 2023's gyro read literally gated the Sun vector (NIS about 320) and
restarted every 10 s for 330 s; with the sum it restarts twice and is valid 20 s after the
eclipse.  A start (without a prior, or against a prior its first single frame
contradicts) sets the bias covariance to the prior's.

The single-frame solver is the registry's generic ``map_nlp``
(:mod:`attopt.solvers.map_nlp`): it accepts every measurement type with a
symbolic model, the very models the filters use, starts without a prior from
the 24 rotations of the octahedral group (no attitude farther than 62.8 deg
from one of them) and returns the inverse Fisher information as covariance.
A solution is used only if it converged, its covariance determines every axis
(largest sigma at most ``max_attitude_sigma``) and its residuals pass the
chi-square test of ``m - 3`` degrees of freedom at ``consistency_false_alarm``
(``2 L``, ``L`` the MAP loss at the estimate; ``m`` the measurement's rows,
lenient for unit vectors whose three rows carry two independent components):
a measurement the model does not fit (a burst of outliers) gives no restart.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import UnsupportedMeasurementError
from attopt.formulations.gyro import GyroModel
from attopt.formulations.passes import Prior
from attopt.formulations.snapshot import Snapshot
from attopt.solvers.chi_square import chi_square_tail
from attopt.solvers.filters.common import FilterOptions, apply_error, error_vector
from attopt.solvers.sequential import (
    INCONSISTENT,
    INFLATE,
    RESTARTED,
    WAIT,
    Recovery,
    SequentialFilter,
    largest_attitude_sigma,
    rejected_epoch,
)

Array = NDArray[np.float64]

UNKNOWN_ATTITUDE_SIGMA = np.pi
"""Per-axis attitude sigma (rad) of a filter that has no start yet."""


@dataclass(frozen=True)
class SingleFrame:
    """A single-frame attitude and its ``3 x 3`` covariance (body frame, rad^2)."""

    attitude: Rotation
    covariance: Array


def single_frame(
    measurement: AttitudeMeasurement, options: FilterOptions, ambiguity_check: bool = False
) -> SingleFrame | str:
    """The ``map_nlp`` solution of one epoch's ``measurement`` without a prior, or why
    there is none (module docstring): :data:`~attopt.solvers.sequential.INFLATE` when
    the measurement cannot determine the attitude (no symbolic model, no converged
    solution, an axis above ``max_attitude_sigma``), :data:`~attopt.solvers.sequential.WAIT`
    when its residuals fail the chi-square test (a later epoch may fit) or, with
    ``ambiguity_check``, when a second minimum outside its covariance fits about as well
    (``MapNlp.rival``; a later epoch may tell them apart)."""
    from attopt.solvers.map_nlp import MAP_NLP  # here: map_nlp imports the bounds, which import us

    try:
        track = MAP_NLP.solve_sequence([Snapshot.of(measurement)])
    except UnsupportedMeasurementError:  # no symbolic model: no single frame
        return INFLATE
    covariance = track.covariance[0]
    if not (track.valid[0] and np.all(np.isfinite(covariance))):
        return INFLATE
    if largest_attitude_sigma(covariance) > options.max_attitude_sigma:
        return INFLATE
    dof = measurement.size - 3
    if dof > 0 and chi_square_tail(2.0 * track.loss[0], dof) < options.consistency_false_alarm:
        return WAIT
    attitude = track.attitude()[0]
    if ambiguity_check and MAP_NLP.rival(
        Snapshot.of(measurement), attitude, float(track.loss[0]), covariance
    ):
        return WAIT
    return SingleFrame(attitude, covariance)


def determines(
    filter: SequentialFilter, measurement: AttitudeMeasurement, options: FilterOptions
) -> bool:
    """Whether ``measurement`` alone determines every axis at the filter's attitude: the
    largest sigma of the inverse of its information ``J^T R^-1 J`` (its finite rows) at
    most ``options.max_attitude_sigma``.  A cheap test (one model evaluation) before the
    single frame's NLP (tens of milliseconds), which the epochs that cannot give one (a
    single unit vector) would otherwise run in vain."""
    _, jacobian = measurement.predict(filter.attitude)
    rows = np.all(np.isfinite(jacobian[0]), axis=1)
    if rows.sum() < 3:
        return False
    noise = np.asarray(measurement.noise_covariance_at(filter.attitude), dtype=float)
    noise = np.diag(noise) if noise.ndim == 1 else noise
    h = jacobian[0][rows]
    information = h.T @ np.linalg.lstsq(noise[np.ix_(rows, rows)], h, rcond=None)[0]
    smallest = np.linalg.eigvalsh(0.5 * (information + information.T))[0]
    return bool(smallest * options.max_attitude_sigma**2 >= 1.0)


def filter_frame(
    filter: SequentialFilter, measurement: AttitudeMeasurement, options: FilterOptions
) -> SingleFrame | str:
    """The single frame ``filter`` starts or restarts from: :func:`single_frame` of the
    measurement; where its residuals fail their test, that of the measurement as the
    filter sees it (``filter.single_frame_view``: transmitter offsets at their prior),
    if the filter sees it otherwise, checked for a second minimum.  The widened frame
    only as the fallback: its loss is flatter, and on the first epoch of ``adsb-sky``'s
    ideal sky it lay 52 deg off (sigmas 1.2-4.5 deg, no rival found from the
    multi-start attitudes) where the plain frame was right."""
    frame = single_frame(measurement, options)
    if frame != WAIT:
        return frame
    view = filter.single_frame_view(measurement)
    return frame if view is measurement else single_frame(view, options, ambiguity_check=True)


def contradicts(filter: SequentialFilter, frame: SingleFrame, false_alarm: float) -> bool:
    """Whether the filter's attitude and a single-frame solution contradict each other:
    ``d^T (P_a + P_s)^-1 d`` (``d`` their error vector, ``P_a`` the filter's attitude
    covariance, ``P_s`` the frame's) beyond the chi-square(3) quantile ``1 - false_alarm``,
    the innovation test of an attitude observation (Bar-Shalom, Li and Kirubarajan 2001
    sec. 5.4.2)."""
    d = error_vector(frame.attitude, filter.attitude)
    s = filter.covariance[:3, :3] + frame.covariance
    with np.errstate(invalid="ignore", over="ignore"):
        statistic = float(d @ np.linalg.solve(s, d))
    return not chi_square_tail(statistic, 3) >= false_alarm


def fuse(filter: SequentialFilter, frame: SingleFrame) -> dict[str, float]:
    """Update the filter with ``frame`` as an observation of its attitude (module
    docstring): innovation ``nu = error_vector(A_s, A)``, ``S = P_aa + P_s``, gain ``K =
    P H^T S^-1`` with ``H = [I 0]``, the error state ``K nu`` applied to the attitude and
    the rest of the state (the bias), and the Joseph form ``(I - K H) P (I - K H)^T +
    K P_s K^T`` (Markley and Crassidis 2014 eqs. 6.27-6.29).  Returns the epoch's
    counts: ``nis = nu^T S^-1 nu`` with 3 degrees of freedom."""
    covariance = filter.covariance
    innovation = error_vector(frame.attitude, filter.attitude)
    s = covariance[:3, :3] + frame.covariance
    gain = np.linalg.solve(s, covariance[:3, :]).T
    correction = gain @ innovation
    filter.attitude = apply_error(correction[:3], filter.attitude)
    other = filter.state[1]  # the bias of the gyro filters
    setattr(filter, other, getattr(filter, other) + correction[3:])
    keep = np.eye(covariance.shape[0])
    keep[:, :3] -= gain
    filter.covariance = keep @ covariance @ keep.T + gain @ frame.covariance @ gain.T
    return {"nis": float(innovation @ np.linalg.solve(s, innovation)), "nis_dof": 3.0}


@dataclass
class SingleFrameStart(Recovery):
    """The start of the online smoother (:mod:`attopt.solvers.smoother.online`) against a
    prior (``recovery = "restart"``): at the first epoch with a measurement, if that
    epoch's single frame does not contradict the prediction (:func:`contradicts`), the
    node is linearised at the single frame instead of the prediction
    (``filter.start_at``); the prior and measurement factors are unchanged, so only the
    basin the optimiser starts in changes (module docstring, start against a prior).
    Lost tracks are not re-acquired (:meth:`restart`: the monitor's inflation, as
    without a recovery)."""

    options: FilterOptions
    checked: bool = False

    def before_update(
        self, filter: SequentialFilter, measurement: AttitudeMeasurement
    ) -> dict[str, float] | None:
        """At the first measurement epoch: move the linearisation point; never replaces
        the update."""
        if self.checked or self.options.recovery != "restart":
            return None
        self.checked = True
        frame = filter_frame(filter, measurement, self.options)
        if isinstance(frame, SingleFrame) and not contradicts(
            filter, frame, self.options.consistency_false_alarm
        ):
            filter.start_at(frame.attitude)
        return None

    def restart(
        self, filter: SequentialFilter, measurement: AttitudeMeasurement, verdict: str
    ) -> str:
        """:data:`~attopt.solvers.sequential.INFLATE` (class docstring)."""
        return INFLATE


def unknown_prior(model: GyroModel) -> Prior:
    """The start of a filter without a prior: unknown attitude (:data:`UNKNOWN_ATTITUDE_SIGMA`),
    zero bias with the model's initial bias sigma."""
    variances = [UNKNOWN_ATTITUDE_SIGMA**2] * 3 + [model.initial_bias_sigma**2] * 3
    return Prior(Rotation.identity(), np.diag(variances), bias=np.zeros(3))


@dataclass
class SingleFrameRecovery(Recovery):
    """Start and restarts of a gyro filter from single-frame solutions (module docstring).

    Attributes:
        options: the filter's options (``recovery``, the tests' limits).
        bias_covariance: ``(3, 3)`` the prior's bias covariance, added to the filter's by a
            re-acquisition.
        started: whether the filter has an attitude (a prior, or a single frame).
        checked: whether the first measurement epoch (with :attr:`awaits_frame`, the first
            that determines every axis) has been checked against the prior.
        awaits_frame: the check waits for an epoch that determines every axis
            (:attr:`pending`): the prior's attitude sigma exceeds
            ``options.max_attitude_sigma``, or the first update from an unconfirmed prior
            contradicted it (``contradicted``).
        seen: whether a measurement epoch has been seen (the first is always tried).
        unconfirmed: the check of the prior found no single frame and the filter went on
            from the prior; the update that follows has not been judged yet
            (:meth:`after_update`).
        contradicted: that update rejected at least as many observations as it used.
    """

    options: FilterOptions
    bias_covariance: Array
    started: bool = True
    checked: bool = False
    awaits_frame: bool = False
    seen: bool = False
    unconfirmed: bool = False
    contradicted: bool = False

    @classmethod
    def of(cls, options: FilterOptions, start: Prior, started: bool) -> SingleFrameRecovery:
        """The recovery of a filter started from ``start``: the pass's prior (``started``)
        or :func:`unknown_prior`."""
        covariance = np.asarray(start.covariance)
        checked = options.recovery != "restart"
        sigma = largest_attitude_sigma(covariance[:3, :3])
        wide = started and not checked and bool(sigma > options.max_attitude_sigma)
        return cls(options, covariance[3:, 3:], started, checked, awaits_frame=wide)

    @property
    def pending(self) -> str:
        """Why the start awaits a single frame: a prior wider than the limit, or one its
        first update contradicted, that no single frame has checked yet (module
        docstring); else empty."""
        if not self.awaits_frame or self.checked:
            return ""
        if self.contradicted:
            return "a prior no single frame confirmed, contradicted by its first update"
        return (
            f"started from a prior wider than {np.degrees(self.options.max_attitude_sigma):g} "
            "deg that no single frame has confirmed yet"
        )

    def before_update(
        self, filter: SequentialFilter, measurement: AttitudeMeasurement
    ) -> dict[str, float] | None:
        """Without a start: start from the epoch's single frame (or wait for one); at the
        first measurement epoch: restart if the prior contradicts its single frame, else
        update with the single frame (:func:`fuse`); with :attr:`awaits_frame` (no single
        frame there), at the first epoch whose measurement alone determines every axis
        (:func:`determines`): restart from its single frame as a re-acquisition does
        (module docstring)."""
        if self.started and self.checked:
            return None
        first, self.seen = not self.seen, True
        if self.awaits_frame and not first and not determines(filter, measurement, self.options):
            return None
        frame = filter_frame(filter, measurement, self.options)
        if not self.started:
            if not isinstance(frame, SingleFrame):
                return {}
            self.started = self.checked = True
            return self._apply(filter, frame)
        if not isinstance(frame, SingleFrame):
            # no frame: checked, unless a wide prior awaits an epoch that determines the
            # attitude (after the first epoch, this one does: it passed the test above)
            self.checked = not (self.awaits_frame and first) or determines(
                filter, measurement, self.options
            )
            self.unconfirmed = self.checked
            return None
        self.checked = True
        if not first:  # the updates since the wide prior were linearised far from the truth
            return self._apply(filter, frame, updated=True)
        if contradicts(filter, frame, self.options.consistency_false_alarm):
            return self._apply(filter, frame)
        return fuse(filter, frame)

    def after_update(self, counts: Mapping[str, float]) -> None:
        """The update after going on from an unconfirmed prior: if it rejected at least as
        many observations as it used (:func:`~attopt.solvers.sequential.rejected_epoch`),
        the prior is contradicted, and the filter waits for a single frame as from a wide
        prior (module docstring)."""
        if not self.unconfirmed:
            return
        self.unconfirmed = False
        names = ("n_gated", "n_used", "n_unpredictable")
        if rejected_epoch(*(counts.get(name, 0.0) for name in names)):
            self.contradicted = self.awaits_frame = True
            self.checked = False

    def restart(
        self, filter: SequentialFilter, measurement: AttitudeMeasurement, verdict: str
    ) -> str:
        """Restart after a lost track, or after persistently inconsistent innovations when
        the single frame contradicts the estimate (``recovery = "restart"``; else
        :data:`~attopt.solvers.sequential.INFLATE`)."""
        if self.options.recovery != "restart":
            return INFLATE
        frame = filter_frame(filter, measurement, self.options)
        if not isinstance(frame, SingleFrame):
            return frame
        if verdict == INCONSISTENT and not contradicts(
            filter, frame, self.options.consistency_false_alarm
        ):
            return WAIT
        self.checked = True  # a single frame now gives the attitude
        self._apply(filter, frame, updated=True)
        return RESTARTED

    def _apply(
        self, filter: SequentialFilter, frame: SingleFrame, updated: bool = False
    ) -> dict[str, float]:
        """Set the attitude and covariance from ``frame`` and keep the bias estimate, with
        the prior's bias covariance (:attr:`bias_covariance`) at a start, added to the
        filter's own at a re-acquisition (``updated``: the filter has updated since its
        start; module docstring), without attitude-bias correlation (the error state's
        attitude block first, as the gyro filters')."""
        covariance = np.zeros_like(filter.covariance)
        covariance[:3, :3] = frame.covariance
        own = filter.covariance[3:, 3:] if updated else 0.0
        covariance[3:, 3:] = own + self.bias_covariance
        filter.reset(frame.attitude, covariance)
        return {"restarts": 1.0, "nis": np.nan, "nis_dof": 0.0}
