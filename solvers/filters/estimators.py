"""The gyro-aided filters as registry estimators: ``mekf``, ``usque`` and ``rts``, and
``mekf_offsets`` and ``usque_offsets`` with transmitter power offsets.

Each takes a :class:`~attopt.formulations.passes.Pass` with a gyro record
and a prior (an attitude-only prior gets zero bias with the gyro model's
initial bias sigma, :func:`~attopt.solvers.filters.common.gyro_prior`) and
any :class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement`s,
and returns the :class:`~attopt.solvers.results.Track` of
:func:`attopt.solvers.sequential.run_filter` (state ``("attitude", "bias")``).
The epochs need not be gyro sample times.

Example::

    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> from attopt.formulations.gyro import MEMS_GYRO
    >>> from attopt.formulations.passes import GyroRecord, Pass, Prior
    >>> t = np.arange(10.0) + 0.05  # between the 10 Hz gyro's samples
    >>> gyro = GyroRecord(np.arange(0.0, 10.01, 0.1), np.zeros((100, 3)), MEMS_GYRO)
    >>> body = reference = np.tile(np.eye(3)[:2], (10, 1, 1))
    >>> prior = Prior(Rotation.identity(), np.radians(1.0) ** 2 * np.eye(3))
    >>> pass_ = Pass.from_vectors(t, body, reference, 1e-3, gyro, prior)
    >>> track = Mekf().solve(pass_)
    >>> bool(track.valid.all()), track.state
    (True, ('attitude', 'bias'))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from attopt.formulations.attitude_measurement import AttitudeMeasurement, ReferencedMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import Pass
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.estimator import PassEstimator
from attopt.solvers.filters.common import (
    FilterOptions,
    GyroStateFilter,
    check_gyro_pass,
    gyro_monitor,
    gyro_pass,
)
from attopt.solvers.filters.mekf import MekfFilter, MekfOffsetFilter
from attopt.solvers.filters.offsets import OFFSET_PRIOR_SIGMA_DB, OFFSET_TIMEOUT_S, OffsetStates
from attopt.solvers.filters.recovery import SingleFrameRecovery, unknown_prior
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.filters.usque import UsqueFilter, UsqueOffsetFilter
from attopt.solvers.results import Track
from attopt.solvers.sequential import run_filter


@dataclass(frozen=True, repr=False)
class GyroFilter(PassEstimator):
    """A gyro-aided filter run through the sequential loop: its steps are ``steps``.

    Attributes:
        filter: fault handling (gating, gyro gaps, validity, lost track).
    """

    filter: FilterOptions = field(default_factory=FilterOptions)

    steps: ClassVar[type[GyroStateFilter]]
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)

    def offset_states(self, pass_: Pass) -> OffsetStates | None:
        """The transmitter offsets the filter carries on ``pass_`` (``None``: none)."""
        return None

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The filtered track (``initial`` unused), started and restarted from single-frame
        solutions as ``filter.recovery`` says (:mod:`attopt.solvers.filters.recovery`;
        without a prior from the first one); a smoothable filter's keeps the history an
        RTS pass needs."""
        inputs = gyro_pass(pass_, self, self.filter, needs_prior=False)
        start = inputs.prior if inputs.prior is not None else unknown_prior(inputs.model)
        return run_filter(
            self.steps(inputs.gyro, inputs.model, start, self.filter, self.offset_states(pass_)),
            inputs.t,
            inputs.measurements,
            gyro_monitor(self.filter, start),
            self.filter,
            self.name,
            SingleFrameRecovery.of(self.filter, start, started=inputs.prior is not None),
        )


@dataclass(frozen=True, repr=False)
class Mekf(GyroFilter):
    """The multiplicative EKF with gyro bias (:mod:`attopt.solvers.filters.mekf`)."""

    name: ClassVar[str] = "mekf"
    description: ClassVar[str] = (
        "multiplicative EKF with gyro bias (Liu et al. 2023 secs. 4.2-4.5, Joseph form)"
    )
    steps: ClassVar[type[GyroStateFilter]] = MekfFilter


@dataclass(frozen=True, repr=False)
class Usque(GyroFilter):
    """The unscented quaternion estimator with gyro bias (:mod:`attopt.solvers.filters.usque`)."""

    name: ClassVar[str] = "usque"
    description: ClassVar[str] = (
        "unscented quaternion estimator with gyro bias (Crassidis and Markley 2003; "
        "Pimienta-Penalver and Crassidis sec. V.B)"
    )
    steps: ClassVar[type[GyroStateFilter]] = UsqueFilter


OFFSET_MAX_ATTITUDE_SIGMA = float(np.radians(5.0))
"""Default ``FilterOptions.max_attitude_sigma`` (rad) of the filters with offsets
(:class:`OffsetFilter`)."""


@dataclass(frozen=True, repr=False)
class OffsetFilter(GyroFilter):
    """A gyro-aided filter that also estimates each transmitter's power offset (the
    measurements' ``sources``) as an augmented state (:mod:`attopt.solvers.filters.offsets`).

    It accepts the measurements that carry ``sources``: SNRs
    (:class:`~attopt.formulations.snr_measurement.SnrMeasurement`), also re-expressed
    for another frame (:class:`~attopt.formulations.attitude_measurement.ReferencedMeasurement`).

    Its default ``filter`` flags epochs whose attitude sigma exceeds
    :data:`OFFSET_MAX_ATTITUDE_SIGMA` (5 deg, not the plain filters' 15 deg): with every
    aircraft's power free, one epoch constrains the attitude weakly (sigmas of 6-8 deg
    after a first update on ``adsb-snr``), and from such a spread the linearised
    filters were measured to drift into a wrong attitude that the offsets then absorb,
    so that the innovations do not reveal it (``adsb-sky``'s power sky with the
    ``liu2023`` gyro: 135 deg off at sigmas of 14-17 deg).

    Attributes:
        offset_sigma: prior standard deviation of each offset (dB).
        offset_timeout_s: a transmitter not heard for longer is marginalised (s).
        offset_rate_sigma: the offsets' random-walk density (dB / sqrt(s); 0: each
            offset a constant).
    """

    filter: FilterOptions = field(
        default_factory=lambda: FilterOptions(max_attitude_sigma=OFFSET_MAX_ATTITUDE_SIGMA)
    )
    offset_sigma: float = OFFSET_PRIOR_SIGMA_DB
    offset_timeout_s: float = OFFSET_TIMEOUT_S
    offset_rate_sigma: float = 0.0

    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (
        SnrMeasurement,
        ReferencedMeasurement,
    )

    def __post_init__(self) -> None:
        self.empty_offsets()  # raises if out of range

    def offset_states(self, pass_: Pass) -> OffsetStates:
        """Empty offsets with the prior and timeout.

        Raises:
            InvalidObservationError: no measurement of ``pass_`` has sources.
        """
        if all(m is None or m.sources is None for m in pass_.measurements()):
            raise InvalidObservationError(
                f"{self.name} estimates transmitter offsets: no measurement has sources"
            )
        return self.empty_offsets()

    def empty_offsets(self) -> OffsetStates:
        """Empty offsets with this filter's prior, timeout and random walk."""
        return OffsetStates(self.offset_sigma, self.offset_timeout_s, self.offset_rate_sigma)


@dataclass(frozen=True, repr=False)
class MekfOffsets(OffsetFilter):
    """The MEKF with transmitter power offsets (:class:`OffsetFilter`).

    Example::

        >>> MekfOffsets(offset_sigma=3.0).offset_sigma
        3.0
    """

    name: ClassVar[str] = "mekf_offsets"
    description: ClassVar[str] = (
        "multiplicative EKF with gyro bias and each transmitter's power offset as an "
        "augmented state"
    )
    steps: ClassVar[type[GyroStateFilter]] = MekfOffsetFilter


@dataclass(frozen=True, repr=False)
class UsqueOffsets(OffsetFilter):
    """USQUE with transmitter power offsets (:class:`OffsetFilter`).

    Example::

        >>> UsqueOffsets().offset_timeout_s
        30.0
    """

    name: ClassVar[str] = "usque_offsets"
    description: ClassVar[str] = (
        "unscented quaternion estimator with gyro bias and each transmitter's power "
        "offset as an augmented state"
    )
    steps: ClassVar[type[GyroStateFilter]] = UsqueOffsetFilter


@dataclass(frozen=True, repr=False)
class Rts(PassEstimator):
    """The multiplicative RTS backward pass over an MEKF track (:mod:`attopt.solvers.filters.rts`).

    Attributes:
        forward: the MEKF it runs when not given one's track; its fault
            handling is also the smoothed track's validity rules.
    """

    forward: Mekf = field(default_factory=Mekf)

    name: ClassVar[str] = "rts"
    description: ClassVar[str] = "multiplicative Rauch-Tung-Striebel smoother over the MEKF"
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)
    starts_from: ClassVar[tuple[str, ...]] = ("mekf",)

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The smoothed track of ``initial`` (an MEKF's on this pass), else of the forward
        MEKF run here.

        Raises:
            InvalidObservationError: no gyro record or prior, or ``initial`` has another
                number of epochs or no history.
        """
        check_gyro_pass(pass_, self, needs_prior=False)
        if initial is None:
            initial = self.forward.solve(pass_)
        if len(initial) != len(pass_):
            raise InvalidObservationError(
                f"the track to smooth has {len(initial)} epochs, the pass {len(pass_)}"
            )
        return rts_smooth(initial, self.forward.filter, self.name)
