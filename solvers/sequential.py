"""The one sequential loop of every recursive estimator: predict, update, monitor, record.

A recursive estimator is a :class:`SequentialFilter`, an object holding its
state in the manner of filterpy's filters: the attitude ``A`` (reference ->
body) as :attr:`~SequentialFilter.attitude`, one more 3-vector named by its
``state`` (``bias`` for the gyro-aided filters, ``rate`` for Yang et al.
2014's EKF) and the error-state :attr:`~SequentialFilter.covariance`, with two
steps:

* :meth:`~SequentialFilter.predict` ``(t)`` propagates the state to time ``t``
  (and sets :attr:`~SequentialFilter.transition`, the error-state transition
  an RTS pass needs);
* :meth:`~SequentialFilter.update` ``(measurement)`` processes one epoch's
  measurement and returns its counts (``None``: no measurement, nothing to
  count; as in filterpy, ``update(None)`` is allowed and leaves the
  prediction).

The MEKF, USQUE (:mod:`attopt.solvers.filters`), the online smoother
(:mod:`attopt.solvers.smoother.online`) and Yang et al. 2014's EKF
(:mod:`attopt.solvers.doa.ekf`) are such objects; their modules hold only the
equations of the two steps.  :func:`run_filter` walks the epochs of a pass
with one of them::

    for each epoch k:
        predict to t_k, record the prediction and its transition (for RTS)
        update with the epoch's measurement
        TrackMonitor: lost-track detection, covariance inflation
        record the estimate; stop at a non-finite state

and assembles the :class:`~attopt.solvers.results.Track` with the validity
rules of :func:`filter_result`.  The same steps by hand, e.g. with the MEKF
(:class:`attopt.solvers.filters.mekf.MekfFilter`; ``gyro`` the pass's prepared
gyro timeline, :func:`attopt.solvers.filters.common.gyro_pass`)::

    f = MekfFilter(gyro, model, prior, FilterOptions())
    f.predict(t[0])
    counts = f.update(measurement)
    f.attitude, f.bias, f.covariance

Lost track (:class:`TrackMonitor`): after ``max_rejected_epochs`` consecutive
measurement epochs with at least as many gated or unpredictable observation blocks
as used ones (:func:`rejected_epoch`), epochs are flagged as a lost track until one
is accepted; a monitor with an ``inflation`` then adds it to the covariance
(repeatedly, every ``max_rejected_epochs`` such epochs) to re-acquire,
counted as ``recoveries`` (the gyro filters inflate the attitude by
``recover_sigma^2 I`` and the bias by the prior's bias covariance,
:mod:`attopt.solvers.filters.common`).

Consistency (:func:`inconsistent_epochs`): filters that record each update's
normalised innovation squared and its rows (``nis``, ``nis_dof``) have the epochs
whose last ``consistency_window`` updates fail the chi-square test flagged
``inconsistent`` when the track is assembled; the test reads the recorded
innovations, so the same rule serves the loop here and a filter whose epoch loop
runs in CasADi (Yang et al. 2014's EKF on unit vectors).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import ConvergenceError, ModelMismatchError
from attopt.solvers.chi_square import chi_square_tail
from attopt.solvers.results import Track

if TYPE_CHECKING:
    from attopt.solvers.filters.common import FilterOptions

Array = NDArray[np.float64]

DIAGNOSTICS = (
    "nis",
    "nis_dof",
    "n_used",
    "n_gated",
    "n_nan",
    "n_unpredictable",
    "gyro_gap_s",
    "update_iterations",
    "recoveries",
    "restarts",
    "covariance_repairs",
    "n_downweighted",
)
"""Per-epoch counts of the gyro-aided filters (:func:`filter_result`)."""
OFFSET_DIAGNOSTICS = (*DIAGNOSTICS, "offset_nis", "offset_dof")
"""Those of the filters with transmitter offsets: also the offsets' test against their prior."""
NON_FINITE = "filter state became non-finite"


class SequentialFilter(ABC):
    """A recursive estimator's state and its predict and update steps (module docstring).

    Attributes:
        state: names of the error state's three-component blocks, e.g.
            ``("attitude", "bias")``; the non-attitude one is an attribute too.
        diagnostics: names of the counts its steps report.
        smoothable: whether :attr:`transition` is set (an RTS pass can follow).
        attitude: the estimate ``A`` (reference -> body).
        covariance: ``(6, 6)`` covariance of the error state.
        transition: after :meth:`predict`, the error-state transition from the
            previous time (``None`` for filters without one).
    """

    state: ClassVar[tuple[str, str]] = ("attitude", "bias")
    diagnostics: ClassVar[tuple[str, ...]] = DIAGNOSTICS
    smoothable: ClassVar[bool] = False

    attitude: Rotation
    covariance: Array
    transition: Array | None = None

    @abstractmethod
    def predict(self, t: float) -> dict[str, float]:
        """Propagate the state to time ``t``; the propagation's counts."""

    @abstractmethod
    def update(self, measurement: AttitudeMeasurement | None) -> dict[str, float] | None:
        """Process one epoch's measurement (``None``: none); its counts, or ``None`` when
        there is nothing to count."""

    def single_frame_view(self, measurement: AttitudeMeasurement) -> AttitudeMeasurement:
        """The measurement as a single-frame solution for a start or restart sees it (the
        measurement itself; a filter that carries more of the model than the attitude
        gives its prior here)."""
        return measurement

    def reset(self, attitude: Rotation, covariance: Array) -> None:
        """Restart the estimate at ``attitude`` with the error state's ``covariance`` (a
        recovery's restart from a single frame); the non-attitude block is kept."""
        self.attitude, self.covariance = attitude, covariance

    @property
    def vector(self) -> Array:
        """The state's non-attitude block (the ``bias`` or ``rate`` attribute)."""
        return getattr(self, next(name for name in self.state if name != "attitude"))

    def attitude_values(self) -> Array:
        """The attitude as the filter carries it, recorded exactly for a backward pass:
        a scalar-last quaternion ``(4,)`` (or a ``(3, 3)`` matrix, :func:`rotations`)."""
        return self.attitude.as_quat()


def rotations(values: ArrayLike) -> Rotation:
    """Rotations from attitudes recorded by :meth:`SequentialFilter.attitude_values`:
    ``(..., 4)`` quaternions (normalised by ``Rotation.from_quat``) or ``(..., 3, 3)``
    matrices."""
    values = np.asarray(values, dtype=float)
    return Rotation.from_quat(values) if values.shape[-1] == 4 else Rotation.from_matrix(values)


def stored_rotations(quaternion: ArrayLike) -> Rotation:
    """Rotations of a track's unit quaternions exactly as stored.

    ``Rotation.from_quat`` normalises them again, which changes the last bit of
    about a third; an estimate handed from one estimator to another (a start)
    keeps its bits this way.
    """
    return Rotation(np.asarray(quaternion, dtype=float), normalize=False)


def largest_attitude_sigma(covariance: ArrayLike) -> np.ndarray:
    """The largest standard deviation of the attitude covariance ``(..., 3, 3)``: the
    square root of its largest diagonal entry, the measure ``max_attitude_sigma`` limits
    (``FilterOptions``).

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.sequential import largest_attitude_sigma
        >>> float(largest_attitude_sigma(np.diag([1e-4, 4e-4, 9e-4])))
        0.03
    """
    return np.sqrt(np.max(np.diagonal(np.asarray(covariance), axis1=-2, axis2=-1), axis=-1))


def rejected_epoch(n_gated: float, n_used: float, n_unpredictable: float = 0.0) -> bool:
    """An epoch whose rejected observation blocks are at least as many as its used ones:
    gated, or ``n_unpredictable`` blocks the model cannot predict at the estimate (an SNR
    received from an aircraft outside every main lobe at the estimated attitude, which the
    model says cannot be received).

    With two vectors, a Sun vector rejected while the magnetometer is used
    counts (the filter has lost the rotation about the field); with many SNRs
    a few gated outliers do not; nor do a few SNRs at the edge of a main lobe,
    while an epoch none of whose SNRs the estimate can predict does (measured in
    ``adsb-sky``'s real sky: without them, such epochs reset the lost-track count
    and the online smoother was reported valid 90-180 deg off).
    """
    rejected = n_gated + n_unpredictable
    return rejected > 0 and rejected >= n_used


LOST = "lost"
"""A :meth:`TrackMonitor.due` verdict: the track is lost (every ``max_rejected_epochs``
rejected epochs)."""
STILL_LOST = "still lost"
"""The verdict at the other measurement epochs of a lost track: a restart is tried at
each (the covariance is inflated only at :data:`LOST`)."""
INCONSISTENT = "inconsistent"
"""A :meth:`TrackMonitor.due` verdict: the consistency window has failed for
``max_rejected_epochs`` consecutive updates."""


@dataclass
class TrackMonitor:
    """Detects a lost track and persistently inconsistent innovations (module docstring).

    Attributes:
        max_rejected_epochs: consecutive :func:`rejected_epoch` measurement
            epochs after which the track counts as lost; also the consecutive
            updates with a failing consistency window that count as persistent.
        inflation: added to the covariance by :meth:`check` every
            ``max_rejected_epochs`` rejected epochs (``recoveries`` is set in that
            epoch's counts); ``None``: never (the online smoother, which has no
            re-acquisition).
        consistency_window: updates in the online consistency test (the window of
            :func:`inconsistent_epochs`, restarted by :meth:`restarted`); 0: none.
        consistency_false_alarm: that test's false-alarm probability.
        rejected: consecutive rejected epochs so far (an accepted one resets it).
        since_inflation: those since the last inflation (or restart attempt).
        failing: consecutive updates whose window failed, since the last verdict.
    """

    max_rejected_epochs: int
    inflation: Array | None = None
    consistency_window: int = 0
    consistency_false_alarm: float = 1e-6
    rejected: int = 0
    since_inflation: int = 0
    failing: int = 0
    window: list[tuple[float, float]] = field(default_factory=list)

    @property
    def lost(self) -> bool:
        """Whether the track is lost (epochs without a measurement keep the state)."""
        return self.rejected >= self.max_rejected_epochs

    def due(self, counts: dict[str, float]) -> str | None:
        """Count an epoch's update ``counts``; :data:`LOST` every ``max_rejected_epochs``
        rejected epochs, :data:`INCONSISTENT` after ``max_rejected_epochs`` consecutive
        updates whose window fails the chi-square test, else ``None``."""
        n_used = counts.get("n_used", 0.0)
        if rejected_epoch(counts.get("n_gated", 0.0), n_used, counts.get("n_unpredictable", 0.0)):
            self.rejected += 1
            self.since_inflation += 1
        elif n_used > 0:
            self.rejected = self.since_inflation = 0
        self._observe(counts.get("nis", np.nan), counts.get("nis_dof", 0.0))
        if self.since_inflation >= self.max_rejected_epochs:
            self.since_inflation = 0
            return LOST
        if self.failing >= self.max_rejected_epochs:
            self.failing = 0
            return INCONSISTENT
        return None

    def _observe(self, nis: float, dof: float) -> None:
        """Add an update to the window and test it (:func:`inconsistent_epochs`' rule)."""
        if not (self.consistency_window and np.isfinite(nis) and dof > 0):
            return
        self.window = [*self.window[1 - self.consistency_window :], (nis, dof)]
        # summed in order as np.sum(window, axis=0) does, without building an array
        total, rows = sum(n for n, _ in self.window), sum(d for _, d in self.window)
        failed = chi_square_tail(total, rows) < self.consistency_false_alarm
        self.failing = self.failing + 1 if failed else 0

    def check(self, counts: dict[str, float], covariance: Array) -> Array:
        """The covariance to carry on with after an epoch's update ``counts``: inflated
        when :meth:`due` finds the track lost."""
        if self.due(counts) != LOST or self.inflation is None:
            return covariance
        counts["recoveries"] = 1.0
        return covariance + self.inflation

    def restarted(self) -> None:
        """Forget the counts and the window: the filter was restarted."""
        self.rejected = self.since_inflation = self.failing = 0
        self.window = []


RESTARTED, WAIT, INFLATE = "restarted", "wait", "inflate"
"""Outcomes of :meth:`Recovery.restart`: the state was replaced; no restart now but
one is possible later (no inflation); none possible (the monitor's inflation)."""


class Recovery(ABC):
    """Starts and restarts a filter from outside its own steps (the gyro filters'
    :class:`~attopt.solvers.filters.recovery.SingleFrameRecovery`).

    :func:`run_filter` calls :meth:`before_update` at every epoch with a
    measurement and :meth:`restart` when the :class:`TrackMonitor` gives a verdict;
    an epoch at which either replaces the state has ``restarts = 1`` in its counts,
    its ``nis`` is NaN (the epoch's update no longer describes the state) and the
    consistency window starts again (:func:`filter_result`).
    """

    @abstractmethod
    def before_update(
        self, filter: SequentialFilter, measurement: AttitudeMeasurement
    ) -> dict[str, float] | None:
        """``None``: update as usual; else the counts replacing the update's (the epoch
        (re)started the filter, or it has no start yet)."""

    @abstractmethod
    def restart(
        self, filter: SequentialFilter, measurement: AttitudeMeasurement, verdict: str
    ) -> str:
        """After the monitor's ``verdict`` (:data:`LOST`, :data:`STILL_LOST` or
        :data:`INCONSISTENT`): :data:`RESTARTED`, :data:`WAIT` or :data:`INFLATE`."""

    def after_update(self, counts: Mapping[str, float]) -> None:  # noqa: B027 (optional hook)
        """Called with the counts of every update the filter made itself; nothing by
        default."""

    @property
    def pending(self) -> str:
        """Why the filter's start still awaits its check (:func:`filter_result` flags the
        epochs ``converging: <why>``); empty if it does not, as by default."""
        return ""


def inconsistent_epochs(
    nis: ArrayLike,
    dof: ArrayLike,
    window: int,
    false_alarm: float,
    restarts: ArrayLike | None = None,
) -> NDArray[np.bool_]:
    """The epochs whose last ``window`` updates' innovations fail the chi-square test.

    ``nis`` is each epoch's normalised innovation squared ``nu^T S^-1 nu`` (``S = H P H^T
    + R``; NaN: no update) and ``dof`` its rows: for a consistent filter their sums over
    the updates are chi-square with the summed rows (Bar-Shalom, Li and Kirubarajan 2001
    sec. 5.4.2).  An update epoch fails when ``P(chi2(sum dof) >= sum nis) < false_alarm``
    over it and the ``window - 1`` updates before it (fewer at the start, and never
    before the last of the ``restarts`` epochs at or before it: a restarted filter's
    window starts again); an epoch without an update keeps the verdict of the last
    update before it (none: passes).  The test reads the innovations only, so it flags
    without changing the estimates.

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.sequential import inconsistent_epochs
        >>> nis = np.array([3.1, 2.7, np.nan, 95.0, 3.2, 2.9, 3.0])
        >>> inconsistent_epochs(nis, np.full(7, 3.0), window=2, false_alarm=1e-6).tolist()
        [False, False, False, True, True, False, False]
    """
    nis, dof = np.asarray(nis, dtype=float), np.asarray(dof, dtype=float)
    updates = np.flatnonzero(np.isfinite(nis) & (dof > 0))
    flagged = np.zeros(nis.size, dtype=bool)
    if not updates.size:
        return flagged
    sums = [np.concatenate([[0.0], np.cumsum(v[updates])]) for v in (nis, dof)]
    first = np.maximum(
        np.arange(1, updates.size + 1) - window, _segment_starts(updates, restarts, nis.size)
    )
    total, rows = (c[1:] - c[first] for c in sums)
    failed = chi_square_tail(total, rows) < false_alarm
    last = np.searchsorted(updates, np.arange(nis.size), side="right") - 1
    flagged[last >= 0] = failed[last[last >= 0]]
    return flagged


def _segment_starts(
    updates: NDArray[np.intp], restarts: ArrayLike | None, n: int
) -> NDArray[np.intp]:
    """For each update (epoch indices ``updates``), the index into ``updates`` of the first
    update at or after the last restart at or before it (0 without one)."""
    restart = np.flatnonzero(np.zeros(n) if restarts is None else np.asarray(restarts) > 0)
    if not restart.size:
        return np.zeros(updates.size, dtype=np.intp)
    last = np.searchsorted(restart, updates, side="right") - 1
    begin = np.where(last >= 0, restart[np.maximum(last, 0)], 0)
    return np.searchsorted(updates, begin, side="left")


def converging_epochs(
    nis: ArrayLike, dof: ArrayLike, restarts: ArrayLike, window: int
) -> NDArray[np.bool_]:
    """The epochs from each restart (``restarts > 0``) to its ``window``-th update after it:
    the restarted filter has not yet passed a whole window of the consistency test
    (:func:`inconsistent_epochs`); none with ``window = 0``.

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.sequential import converging_epochs
        >>> nis = np.array([3.0, np.nan, 2.0, np.nan, 3.5, 2.5, 3.0])
        >>> converging_epochs(nis, np.full(7, 3.0), [0, 1, 0, 0, 0, 0, 0], window=2).tolist()
        [False, True, True, True, True, False, False]
    """
    nis, dof = np.asarray(nis, dtype=float), np.asarray(dof, dtype=float)
    flagged = np.zeros(nis.size, dtype=bool)
    if not window:
        return flagged
    updates = np.flatnonzero(np.isfinite(nis) & (dof > 0))
    for k in np.flatnonzero(np.asarray(restarts) > 0):
        after = updates[updates > k]
        stop = after[window - 1] + 1 if after.size >= window else nis.size
        flagged[k:stop] = True
    return flagged


UPDATE_STATISTICS = ("nis", "log_likelihood")
"""Diagnostics of an update, NaN at an epoch without one: its normalised innovation squared
and its innovations' log-likelihood."""


@dataclass
class EpochRecord:
    """Per-epoch outputs collected while filtering (what :func:`filter_result` assembles).

    Attributes:
        n: epochs.
        state: the error state's blocks (:attr:`SequentialFilter.state`).
        names: the diagnostics recorded; the update statistics (:data:`UPDATE_STATISTICS`)
            start NaN, the others zero.
        quaternion: ``(n, 4)`` estimates (NaN until stored).
        vector: ``(n, 3)`` the non-attitude block's estimates (bias or rate).
        covariance: ``(n, 6, 6)`` error-state covariances.
        diagnostics: name -> ``(n,)``.
        reason: ``(n,)`` why an epoch is not valid (empty so far).
    """

    n: int
    state: tuple[str, ...] = ("attitude", "bias")
    names: tuple[str, ...] = DIAGNOSTICS
    quaternion: Array = field(init=False)
    vector: Array = field(init=False)
    covariance: Array = field(init=False)
    diagnostics: dict[str, Array] = field(init=False)
    reason: NDArray[np.object_] = field(init=False)

    def __post_init__(self) -> None:
        size = 3 * len(self.state)
        self.quaternion = np.full((self.n, 4), np.nan)
        self.vector = np.full((self.n, 3), np.nan)
        self.covariance = np.full((self.n, size, size), np.nan)
        self.diagnostics = {name: np.zeros(self.n) for name in self.names}
        for name in UPDATE_STATISTICS:
            if name in self.diagnostics:
                self.diagnostics[name][:] = np.nan
        self.reason = np.full(self.n, "", dtype=object)

    def store(
        self, k: int, filter: SequentialFilter, counts: dict[str, float] | None = None
    ) -> bool:
        """Store epoch ``k``'s ``counts`` and the filter's estimate; ``False`` if the state
        is not finite, in which case epoch ``k`` and all later ones are flagged (the
        loop stops)."""
        for name, value in (counts or {}).items():
            self.diagnostics[name][k] = value
        values, vector, covariance = filter.attitude_values(), filter.vector, filter.covariance
        if not (
            np.isfinite(values).all()
            and np.isfinite(vector).all()
            and np.isfinite(covariance).all()
        ):
            self.reason[k:] = NON_FINITE
            return False
        self.quaternion[k] = filter.attitude.as_quat()
        self.vector[k], self.covariance[k] = vector, covariance
        return True


@dataclass(frozen=True)
class FilterHistory:
    """What a backward (RTS) pass needs, per epoch ``k``.

    ``predicted_*`` is the estimate at epoch ``k`` before its update,
    ``transition[k]`` the error-state transition from epoch ``k - 1`` (the
    prior for ``k = 0``) to epoch ``k``; ``filtered_*`` the estimate after it.
    Attitudes are as the filter carries them (quaternions or matrices,
    :func:`rotations`), ``*_vector`` the non-attitude block (bias or rate).
    """

    predicted_attitude: Array
    predicted_vector: Array
    predicted_covariance: Array
    transition: Array
    filtered_attitude: Array
    filtered_vector: Array
    filtered_covariance: Array


class _HistoryRecorder:
    """Collects a :class:`FilterHistory` during :func:`run_filter`."""

    def __init__(self, n: int, filter: SequentialFilter) -> None:
        shape = np.shape(filter.attitude_values())
        size = filter.covariance.shape[0]
        self.predicted_attitude = np.full((n, *shape), np.nan)
        self.filtered_attitude = np.full((n, *shape), np.nan)
        self.predicted_vector = np.full((n, 3), np.nan)
        self.predicted_covariance = np.full((n, size, size), np.nan)
        self.transition = np.full((n, size, size), np.nan)

    def predicted(self, k: int, filter: SequentialFilter) -> None:
        self.predicted_attitude[k] = filter.attitude_values()
        self.predicted_vector[k] = filter.vector
        self.predicted_covariance[k] = filter.covariance
        self.transition[k] = filter.transition

    def history(self, record: EpochRecord) -> FilterHistory:
        return FilterHistory(
            predicted_attitude=self.predicted_attitude,
            predicted_vector=self.predicted_vector,
            predicted_covariance=self.predicted_covariance,
            transition=self.transition,
            filtered_attitude=self.filtered_attitude,
            filtered_vector=record.vector,
            filtered_covariance=record.covariance,
        )


def _merged(predicted: dict[str, float], updated: dict[str, float]) -> dict[str, float]:
    """An epoch's counts: the update's, and the propagation's (counts of one name add up)."""
    out = dict(updated)
    for name, value in predicted.items():
        out[name] = out[name] + value if name in out else value
    return out


def run_filter(
    filter: SequentialFilter,
    t: ArrayLike,
    measurements: Sequence[AttitudeMeasurement | None],
    monitor: TrackMonitor,
    options: FilterOptions,
    method: str,
    recovery: Recovery | None = None,
) -> Track:
    """Walk the epochs ``t`` with ``filter`` (module docstring) and assemble the track.

    At each epoch: :meth:`~SequentialFilter.predict` to ``t[k]``, the
    prediction recorded (smoothable filters), :meth:`~SequentialFilter.update`
    with ``measurements[k]`` (unless the ``recovery``'s
    :meth:`~Recovery.before_update` (re)starts the filter there), the
    ``monitor``'s verdict on its counts (:meth:`TrackMonitor.due`, or
    :data:`STILL_LOST` at any other epoch of a lost track): a restart by the
    ``recovery``, else, at :data:`LOST` and unless the ``recovery`` waits for a
    single frame, the monitor's inflation; the estimate recorded.  A non-finite
    state flags that epoch and all later ones and stops the loop.  The track
    (:func:`filter_result` with ``options``' validity rules) keeps a
    :class:`FilterHistory` for smoothable filters.
    """
    t = np.asarray(t, dtype=float)
    record = EpochRecord(t.size, filter.state, filter.diagnostics)
    history = _HistoryRecorder(t.size, filter) if filter.smoothable else None
    lost = np.zeros(t.size, dtype=bool)
    pending = np.full(t.size, "", dtype=object)
    for k, (time, measurement) in enumerate(zip(t, measurements, strict=True)):
        counts = filter.predict(float(time))
        if history is not None:
            history.predicted(k, filter)
        updated = _update(filter, measurement, monitor, recovery)
        if updated is not None:
            counts = _merged(counts, updated)
        lost[k] = monitor.lost
        pending[k] = "" if recovery is None else recovery.pending
        if not record.store(k, filter, counts):
            break
        if history is not None:
            history.filtered_attitude[k] = filter.attitude_values()
    backward = None if history is None else history.history(record)
    return filter_result(method, record, options, t, backward, lost, settling=True, pending=pending)


def _update(
    filter: SequentialFilter,
    measurement: AttitudeMeasurement | None,
    monitor: TrackMonitor,
    recovery: Recovery | None,
) -> dict[str, float] | None:
    """One epoch's update and recovery (:func:`run_filter`); its counts."""
    if measurement is not None and recovery is not None:
        replaced = recovery.before_update(filter, measurement)
        if replaced is not None:
            if replaced.get("restarts"):
                monitor.restarted()
            return replaced
    counts = filter.update(measurement)
    if counts is None:
        return None
    if recovery is not None:
        recovery.after_update(counts)
    verdict = monitor.due(counts)
    if verdict is None and monitor.lost:
        verdict = STILL_LOST
    if verdict is None:
        return counts
    outcome = INFLATE if recovery is None else recovery.restart(filter, measurement, verdict)
    if outcome == RESTARTED:
        monitor.restarted()
        return counts | {"restarts": 1.0, "nis": np.nan, "nis_dof": 0.0}
    if outcome == INFLATE and verdict == LOST and monitor.inflation is not None:
        counts["recoveries"] = 1.0
        filter.covariance = filter.covariance + monitor.inflation
    return counts


def filter_result(
    method: str,
    record: EpochRecord,
    options: FilterOptions,
    t: ArrayLike | None,
    history: FilterHistory | None = None,
    lost: NDArray[np.bool_] | None = None,
    tested: str = "innovations of the last {window} updates",
    settling: bool = False,
    pending: NDArray[np.object_] | None = None,
) -> Track:
    """Assemble a recursive estimator's :class:`~attopt.solvers.results.Track` at the
    epochs ``t``, flagging epochs by these rules (in this order of precedence):

    * a non-finite state (set in ``record``);
    * a gyro gap longer than ``options.max_gyro_gap_s`` (when the record has
      ``gyro_gap_s``);
    * a lost track (``lost``, from the :class:`TrackMonitor`; before the next rule,
      since the recovery's inflation by ``recover_sigma`` is its consequence);
    * an attitude 1-sigma above ``options.max_attitude_sigma``;
    * a start not yet checked (``pending``: the recovery's :attr:`Recovery.pending`, why
      the epoch awaits a single frame: a start from a prior wider than
      ``options.max_attitude_sigma``, or one its first update contradicted, that no single
      frame has yet confirmed), ``converging: <why>``;
    * a restarted filter still converging (:func:`converging_epochs` of the record's
      ``restarts``, when it has them and ``options.consistency_window`` is not 0), or one
      that re-acquired a lost track without a restart (the epochs from the first after
      ``lost`` to the ``consistency_window``-th update since: its first updates are
      linearised where the filter drifted to while lost), or,
      with ``settling`` (the sequential loop's filters), one whose attitude sigma has
      fallen below ``options.max_attitude_sigma`` fewer than
      ``options.consistency_window`` updates before (its consistency test has not yet
      seen a whole window of the determined attitude);
    * inconsistent innovations (:func:`inconsistent_epochs` of the record's ``nis`` and
      ``nis_dof``, when it has both, over ``options.consistency_window`` updates, the
      window starting again at each restart; ``tested`` names what was tested in the
      reason, ``{window}`` standing for the window), or transmitter offsets' estimates
      that contradict their prior (``offset_nis`` against chi-square with ``offset_dof``
      at ``options.consistency_false_alarm``; filters with offsets,
      :meth:`~attopt.solvers.filters.offsets.OffsetStates.prior_test`), whose
      error is :class:`~attopt.formulations.errors.ModelMismatchError` (the others'
      :class:`~attopt.formulations.errors.ConvergenceError`).

    The track has the ``3 x 3`` attitude covariance; its ``loss`` is the
    normalised innovation squared of the epoch's update (``nis``; NaN without
    one); ``bias`` or ``rate`` (the record's vector, by ``record.state``),
    ``state_covariance`` the error state's covariance and ``history`` the
    inputs of a backward pass (smoothable filters).
    """
    attitude = 3 * record.state.index("attitude")
    block = slice(attitude, attitude + 3)
    sigma = largest_attitude_sigma(record.covariance[:, block, block])
    reason = record.reason.copy()
    if "gyro_gap_s" in record.diagnostics:
        long_gap = (record.diagnostics["gyro_gap_s"] > options.max_gyro_gap_s) & (reason == "")
        reason[long_gap] = f"gyro gap longer than {options.max_gyro_gap_s:g} s"
    if lost is not None:
        reason[lost & (reason == "")] = (
            f"lost track: observations gated for {options.max_rejected_epochs} epochs"
        )
    with np.errstate(invalid="ignore"):
        wide = (sigma > options.max_attitude_sigma) & (reason == "")
    reason[wide] = (
        f"attitude not determined: 1-sigma above {np.degrees(options.max_attitude_sigma):g} deg"
    )
    if pending is not None:
        waiting = (pending != "") & (reason == "")
        reason[waiting] = "converging: " + pending[waiting]
    inconsistent = np.zeros(record.n, dtype=bool)
    if {"nis", "nis_dof"} <= set(record.diagnostics) and options.consistency_window:
        nis, dof = record.diagnostics["nis"], record.diagnostics["nis_dof"]
        restarts = record.diagnostics.get("restarts")
        begun = {}  # what (re)started the filter -> the epochs it did
        if restarts is not None:
            begun["restarted from a single-frame solution"] = restarts > 0
        if lost is not None:
            begun["re-acquired after a lost track"] = np.r_[False, lost[:-1] & ~lost[1:]]
        for what, epochs in begun.items():
            converging = converging_epochs(nis, dof, epochs, options.consistency_window)
            reason[converging & (reason == "")] = (
                f"converging: {what}, fewer than {options.consistency_window} updates since"
            )
        if settling:
            with np.errstate(invalid="ignore"):
                undetermined = sigma > options.max_attitude_sigma
            determined = np.r_[undetermined[:-1] & ~undetermined[1:], False]  # the one before
            settled = converging_epochs(nis, dof, determined, options.consistency_window)
            reason[settled & (reason == "")] = (
                f"converging: the attitude 1-sigma fell below "
                f"{np.degrees(options.max_attitude_sigma):g} deg fewer than "
                f"{options.consistency_window} updates before"
            )
        inconsistent = inconsistent_epochs(
            nis, dof, options.consistency_window, options.consistency_false_alarm, restarts
        ) & (reason == "")
        reason[inconsistent] = (
            f"inconsistent: the {tested.format(window=options.consistency_window)} "
            f"fail the chi-square test at {options.consistency_false_alarm:g}"
        )
    if {"offset_nis", "offset_dof"} <= set(record.diagnostics):
        statistic = record.diagnostics["offset_nis"]
        dof = record.diagnostics["offset_dof"]
        tail = np.ones(record.n)
        for k in np.flatnonzero(dof > 0):
            tail[k] = chi_square_tail(statistic[k], dof[k])
        offsets_off = (tail < options.consistency_false_alarm) & (reason == "")
        reason[offsets_off] = (
            "inconsistent: the transmitter offsets' estimates fail the chi-square test "
            f"against their prior at {options.consistency_false_alarm:g}"
        )
        inconsistent |= offsets_off
    valid = reason == ""
    error = np.full(record.n, None, dtype=object)
    error[~valid] = ConvergenceError
    error[inconsistent] = ModelMismatchError
    quaternion = np.where(valid[:, None], record.quaternion, np.nan)
    covariance = np.where(valid[:, None, None], record.covariance, np.nan)
    nis = record.diagnostics.get("nis", np.full(record.n, np.nan))
    vector = next(name for name in record.state if name != "attitude")
    return Track(
        method=method,
        quaternion=quaternion,
        covariance=covariance[:, block, block],
        loss=np.where(valid, nis, np.nan),
        valid=valid,
        reason=reason,
        error=error,
        diagnostics=record.diagnostics,
        t=None if t is None else np.array(t, dtype=float),
        state_covariance=covariance,
        state=record.state,
        history=history,
        **{vector: np.where(valid[:, None], record.vector, np.nan)},
    )
