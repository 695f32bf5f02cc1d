"""The factor-graph smoothers as registry estimators: ``fg_online``.

``fg_online`` is the causal fixed-lag smoother of
:mod:`attopt.solvers.smoother.online`, run by the sequential loop
(:func:`attopt.solvers.sequential.run_filter`) like the filters: a
:class:`~attopt.formulations.passes.Pass` with a gyro record (epochs anywhere
in it) and a prior, any
:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement`s; the
track carries the pass's :class:`~attopt.solvers.smoother.online.OnlineReport`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.passes import Pass
from attopt.solvers.estimator import PassEstimator
from attopt.solvers.filters.common import FilterOptions, gyro_pass
from attopt.solvers.results import Track
from attopt.solvers.sequential import TrackMonitor, run_filter
from attopt.solvers.smoother.online import OnlineFilter, OnlineOptions


@dataclass(frozen=True, repr=False)
class OnlineSmoother(PassEstimator):
    """The online (causal) factor-graph smoother (:mod:`attopt.solvers.smoother.online`).

    Attributes:
        online: the iSAM2 window (lag, relinearisation).
        filter: gating, gyro-gap and validity rules shared with the filters;
            ``max_update_iterations`` bounds the iSAM2 updates per epoch.
            Lost tracks are flagged, never re-acquired (no inflation).
    """

    online: OnlineOptions = field(default_factory=OnlineOptions)
    filter: FilterOptions = field(default_factory=FilterOptions)

    name: ClassVar[str] = "fg_online"
    description: ClassVar[str] = (
        "causal fixed-lag factor-graph smoother over attitude and gyro bias (GTSAM iSAM2)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)

    def __post_init__(self) -> None:
        if self.filter.max_update_iterations < 1:
            raise ValueError("need filter.max_update_iterations >= 1")

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The causal track with its :class:`~attopt.solvers.smoother.online.OnlineReport`
        (``initial`` unused).

        Its ``loss`` (diagnostic ``nis``) is the epoch's normalised innovation
        squared against the predicted covariance, as the MEKF's; diagnostics
        ``n_used``, ``n_gated``, ``n_nan``, ``n_unpredictable`` count
        observation blocks, ``update_iterations`` the iSAM2 updates of the epoch.
        """
        inputs = gyro_pass(pass_, self, self.filter)
        online = OnlineFilter(
            inputs.gyro, inputs.model, inputs.prior, inputs.t, self.online, self.filter
        )
        track = run_filter(
            online,
            inputs.t,
            inputs.measurements,
            TrackMonitor(self.filter.max_rejected_epochs),
            self.filter,
            self.name,
        )
        return online.report(track)
