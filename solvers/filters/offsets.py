"""Transmitter power offsets as augmented states of the MEKF and USQUE.

An SNR row from transmitter ``s`` (the measurement's ``sources``: an aircraft's
ICAO address in ``adsb-snr``) is ``z = h(A) + o_s + v``: Liu et al. 2023 eq. 13
with the transmitter's EIRP off the assumed ``10 lg P0`` by ``o_s`` dB, fixed while
it is in view and unknown to the receiver, prior ``N(0, sigma_o^2)`` (the
transponder classes' spread, docs/adsb_sky.md).  The filters estimate the
offsets of the transmitters in view with the attitude and bias, as augmented
states (Bar-Shalom, Li and Kirubarajan 2001 sec. 8.2's state augmentation for
unknown biases), rather than as consider states (Schmidt 1966): each aircraft is
heard about a hundred times over a couple of minutes while the attitude is held
by the others, so its offset is observable and estimating it recovers accuracy
a consider filter, which keeps every offset at its prior, gives up; both are
consistent.

The joint error state is ``[delta, delta_beta, delta_o_1 .. delta_o_k]``: the
filter keeps its ``6 x 6`` covariance ``P`` of the first two blocks (what the
sequential loop, the monitor and the recoveries see) and here the offsets'
estimates ``o``, their cross-covariance ``C`` ``(6, k)`` with the error state and
their own covariance ``O`` ``(k, k)``:

* *admission*: a source first heard is added with its prior, ``o = 0``, ``O``
  gaining ``sigma_o^2`` on the diagonal, ``C`` a zero column (independent of the
  state so far);
* *propagation*: offsets are constants, so only ``C <- Phi C`` with the error
  state's transition ``Phi`` over the interval (the MEKF's closed form, USQUE's
  statistical one);
* *update*: each row is predicted with its offset inside the model (``10 lg P0 +
  o``, so the reception threshold's truncated model sees it), the linearised
  measurement's rows get ``dh / d o`` in their source's column (1 for the Gaussian
  model), ``H = [H_delta 0 E]``, and the filters' update runs on the joint
  covariance ``[[P C] [C^T O]]``;
* *marginalisation*: a source not heard for ``timeout_s`` is removed (its row and
  column dropped: the marginal of the others is unchanged); if it is heard again
  it is admitted afresh at its prior, which forgets what was learnt about it;
* a filter restart from a single frame clears every offset (their correlation with
  the discarded attitude is meaningless).

Example::

    >>> import numpy as np
    >>> states = OffsetStates(sigma=2.0, timeout_s=30.0)
    >>> joint, rows = states.augment(np.eye(6), np.array([7, 3, 7]), 3, t=0.0)
    >>> joint.shape, rows.index.tolist()
    ((8, 8), [1, 0, 1])
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.solvers.filters.common import STATE_SIZE, Array

OFFSET_PRIOR_SIGMA_DB = 2.0
"""Default prior standard deviation (dB) of a transmitter's power offset (the filters'
and the batch smoother's, ``fg_batch_offsets``)."""
OFFSET_TIMEOUT_S = 30.0
"""Default time (s) after which a transmitter not heard is marginalised."""
UNINFORMED = 1e-6
"""Share of its prior variance the data must have removed from an offset (or a direction
of the offsets) for :meth:`OffsetStates.prior_test` to test it."""


class RowOffsets(NamedTuple):
    """The offsets an update's rows depend on: ``index`` ``(m,)`` the offset of each
    row (its column in the joint state is ``6 + index``; ``-1``: a row without a
    source), ``value`` ``(k,)`` the offsets' estimates before the update."""

    index: NDArray[np.intp]
    value: Array

    def predicted(self, increment: Array) -> Array:
        """Each row's offset ``o + delta_o`` at the joint error state's offset part
        ``increment`` ``(k,)`` (0 for a row without a source)."""
        offsets = np.append(self.value + increment, 0.0)  # index -1: the appended 0
        return offsets[self.index]

    def shifted(self, measurement: AttitudeMeasurement, increment: Array) -> AttitudeMeasurement:
        """``measurement`` with each row's offset :meth:`predicted` inside its model (the
        SNR's ``10 lg P0 + o``, before the reception threshold's truncation:
        :meth:`~attopt.formulations.attitude_measurement.AttitudeMeasurement.with_offsets`);
        itself when no row has a source."""
        if not (self.index >= 0).any():
            return measurement
        return measurement.with_offsets(self.predicted(increment))

    def slopes(self, shifted: AttitudeMeasurement, attitude: Rotation) -> Array:
        """``dh / d o`` ``(m, k)``: each row's slope in its offset's column (the
        ``shifted`` measurement's ``offset_slope`` at ``attitude``: 1 for the Gaussian SNR
        model, the truncated mean's slope for the truncated one), zero elsewhere."""
        rows = np.flatnonzero(self.index >= 0)
        slopes = np.zeros((self.index.size, self.value.size))
        if rows.size:
            slopes[rows, self.index[rows]] = shifted.offset_slope(attitude)[rows]
        return slopes


def shifted(
    measurement: AttitudeMeasurement, offsets: RowOffsets | None, increment: Array
) -> AttitudeMeasurement:
    """``measurement`` as an update predicts it: with its rows' offsets at ``increment``
    (:meth:`RowOffsets.shifted`), or itself without offsets."""
    return measurement if offsets is None else offsets.shifted(measurement, increment)


@dataclass
class OffsetStates:
    """The offsets a filter carries (module docstring).

    Attributes:
        sigma: prior standard deviation of a new offset (dB).
        timeout_s: a source not heard for longer is marginalised.
        rate_sigma: the offsets' random-walk density (dB / sqrt(s); 0: constants).
        ids: ``(k,)`` sorted source identifiers.
        value: ``(k,)`` estimates (dB).
        cross: ``(6, k)`` cross-covariance with the error state.
        own: ``(k, k)`` covariance.
        last_heard: ``(k,)`` time of each source's last update.
        prior_variance: ``(k,)`` each offset's variance before any data: ``sigma^2``
            plus its random walk since admission.
    """

    sigma: float
    timeout_s: float
    rate_sigma: float = 0.0
    ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    value: Array = field(default_factory=lambda: np.zeros(0))
    cross: Array = field(default_factory=lambda: np.zeros((STATE_SIZE, 0)))
    own: Array = field(default_factory=lambda: np.zeros((0, 0)))
    last_heard: Array = field(default_factory=lambda: np.zeros(0))
    prior_variance: Array = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise ValueError("the offsets' prior sigma must be positive")
        if not self.timeout_s > 0:
            raise ValueError("the offsets' timeout must be positive")
        if not self.rate_sigma >= 0:
            raise ValueError("the offsets' random-walk density must be non-negative")

    @property
    def size(self) -> int:
        """Number of offsets carried."""
        return int(self.ids.size)

    def propagate(self, transition: Array, interval: float) -> None:
        """``C <- Phi C`` over an interval of ``interval`` s with the error state's
        transition ``Phi``; ``O <- O + rate_sigma^2 interval I`` (the offsets' random walk)."""
        self.cross = transition @ self.cross
        if self.rate_sigma > 0.0 and self.size:
            growth = self.rate_sigma**2 * interval
            self.own = self.own + growth * np.eye(self.size)
            self.prior_variance = self.prior_variance + growth

    def prior_test(self) -> tuple[float, int]:
        """The estimates against their prior: ``o^T (D - O)^-1 o`` and its degrees of
        freedom, ``D`` the offsets' prior variances (:attr:`prior_variance`).

        For a filter whose model holds, ``D - O`` is the covariance of the estimates
        themselves (the prior's minus the error's), so the statistic is chi-square with
        ``k`` degrees of freedom.  The measurement innovations cannot show a wrong
        attitude whose misfit the offsets absorb; this test can, since the offsets must
        then leave their prior (docs/filters.md).  It is evaluated relative to the prior,
        ``I - D^-1/2 O D^-1/2``, whose entries lie in ``[0, 1]``: offsets, or directions,
        the data have informed by less than :data:`UNINFORMED` of their prior variance
        are left out with their degrees of freedom (their estimates are round-off).
        """
        scale = np.sqrt(self.prior_variance)
        spread = np.eye(self.size) - self.own / np.outer(scale, scale)
        informed = np.diag(spread) > UNINFORMED
        spread = spread[np.ix_(informed, informed)]
        normalised = self.value[informed] / scale[informed]
        if normalised.size == 0:
            return 0.0, 0
        try:
            whitened = np.linalg.solve(np.linalg.cholesky(spread), normalised)
            return float(whitened @ whitened), int(normalised.size)
        except np.linalg.LinAlgError:
            values, vectors = np.linalg.eigh(0.5 * (spread + spread.T))
            kept = values > UNINFORMED
            projected = vectors[:, kept].T @ normalised
            return float(np.sum(projected**2 / values[kept])), int(kept.sum())

    def clear(self) -> None:
        """Forget every offset (a restart of the filter)."""
        self._keep(np.zeros(self.size, dtype=bool))

    def augment(
        self, covariance: Array, sources: NDArray[np.integer] | None, rows: int, t: float
    ) -> tuple[Array, RowOffsets]:
        """The joint covariance ``[[P C] [C^T O]]`` for an update at time ``t`` of ``rows``
        rows from ``sources`` (``None``: rows without sources), and the rows' offsets;
        sources not heard for ``timeout_s`` are marginalised first, new ones admitted."""
        self._keep(self.last_heard >= t - self.timeout_s)
        if sources is None:
            index = np.full(rows, -1, dtype=np.intp)
        else:
            heard = np.unique(np.asarray(sources, dtype=np.int64))
            new = np.setdiff1d(heard, self.ids, assume_unique=True)
            if new.size:
                self._admit(new)
            self.last_heard[np.searchsorted(self.ids, heard)] = t
            index = np.searchsorted(self.ids, sources).astype(np.intp)
        joint = np.block([[covariance, self.cross], [self.cross.T, self.own]])
        return joint, RowOffsets(index, self.value.copy())

    def absorb(self, joint: Array, increment: Array) -> Array:
        """Take the offsets' part of an updated joint covariance and add the offsets'
        ``increment`` to their estimates; the error state's ``6 x 6`` covariance."""
        self.value = self.value + increment
        self.cross = joint[:STATE_SIZE, STATE_SIZE:]
        self.own = joint[STATE_SIZE:, STATE_SIZE:]
        return joint[:STATE_SIZE, :STATE_SIZE]

    def _admit(self, new: NDArray[np.int64]) -> None:
        k, n = self.size, new.size
        ids = np.concatenate([self.ids, new])
        order = np.argsort(ids, kind="stable")
        own = np.zeros((k + n, k + n))
        own[:k, :k] = self.own
        own[k:, k:] = self.sigma**2 * np.eye(n)
        cross = np.concatenate([self.cross, np.zeros((STATE_SIZE, n))], axis=1)
        self.ids = ids[order]
        self.value = np.concatenate([self.value, np.zeros(n)])[order]
        self.cross = cross[:, order]
        self.own = own[np.ix_(order, order)]
        self.last_heard = np.concatenate([self.last_heard, np.zeros(n)])[order]
        variance = np.concatenate([self.prior_variance, np.full(n, self.sigma**2)])
        self.prior_variance = variance[order]

    def _keep(self, keep: NDArray[np.bool_]) -> None:
        """Marginalise the offsets not in ``keep`` (drop their rows and columns)."""
        if keep.all():
            return
        self.ids, self.value = self.ids[keep], self.value[keep]
        self.cross, self.own = self.cross[:, keep], self.own[np.ix_(keep, keep)]
        self.last_heard, self.prior_variance = self.last_heard[keep], self.prior_variance[keep]
