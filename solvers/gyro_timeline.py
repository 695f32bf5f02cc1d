"""The gyro record cut at the measurement epochs: the steps every gyro-aided estimator walks.

Measurement epochs need not be gyro sample times.  A rate-integrating sample
is the mean rate over its interval ``[t_j, t_{j+1})`` (:mod:`attopt.formulations.gyro`),
which, given the record, is also the best estimate of the rate at every
instant of that interval; an epoch inside an interval therefore splits it
into two steps that both carry the sample's rate, with their own lengths.
The filters propagate, and the smoother preintegrates, over these steps, so
each estimate is at its epoch's exact time.

When every epoch is a sample time (to ``1e-6`` of the step) nothing is
split: the steps are the samples and :attr:`GyroTimeline.uniform` holds, and
interval lengths are ``(number of steps) x dt`` exactly as for a uniform
record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gyro import GyroSamples

Array = NDArray[np.float64]

COINCIDENCE = 1e-6
"""An epoch within this fraction of the gyro step of a sample time is at that sample."""


@dataclass(frozen=True)
class GyroTimeline:
    """Gyro steps with the epochs as step boundaries.

    Attributes:
        t: ``(n,)`` step boundaries: the sample times with the epochs inserted.
        rates: ``(n - 1, 3)`` the measured rate of each step (its sample's; NaN
            in a gap).
        dt: ``(n - 1,)`` step lengths (s).
        epochs: ``(N,)`` index into ``t`` of each epoch.
        uniform: no epoch was inserted (``t`` are the sample times).
        sample_dt: the gyro's sampling step (s).
    """

    t: Array
    rates: Array
    dt: Array
    epochs: NDArray[np.intp]
    uniform: bool
    sample_dt: float

    def durations(self, nodes: ArrayLike) -> Array:
        """Lengths (s) of the intervals between consecutive ``nodes`` (indices into ``t``):
        ``steps x dt`` for a uniform timeline, else the difference of the boundary times."""
        nodes = np.asarray(nodes, dtype=np.intp)
        if self.uniform:
            return np.diff(nodes) * self.sample_dt
        return np.diff(self.t[nodes])


def repeated_readings(rates: ArrayLike, limit: int) -> NDArray[np.bool_]:
    """The samples in a run of more than ``limit`` consecutive samples whose reading of one
    axis is exactly the same while another axis's reading changes: a stuck axis.  A sensor
    with white rate noise (``sigma_v > 0``) repeats a reading with probability zero, so
    such a run is a fault, not a measurement; ``limit = 0`` finds none.  A record in which
    every axis repeats (exact samples of a constant rate, a simulation without noise) is
    not one axis stuck and is left alone.  Quantised records repeat readings legitimately
    when the noise is below the quantum: there ``limit`` must exceed the longest
    repetition expected.

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.gyro_timeline import repeated_readings
        >>> rates = np.random.default_rng(0).normal(size=(8, 3))
        >>> rates[2:7, 1] = 0.25  # the y axis stuck for five samples
        >>> repeated_readings(rates, limit=4).astype(int).tolist()
        [0, 0, 1, 1, 1, 1, 1, 0]
        >>> repeated_readings(np.ones((8, 3)), limit=4).any()  # a constant rate, exactly
        np.False_
    """
    rates = np.asarray(rates, dtype=float)
    stuck = np.zeros(rates.shape[0], dtype=bool)
    if not limit or rates.shape[0] <= limit:
        return stuck
    changed = np.vstack([np.ones((1, rates.shape[1]), dtype=bool), rates[1:] != rates[:-1]])
    changes = np.cumsum(changed, axis=0)  # per axis, the run each sample belongs to (+1)
    for axis in range(rates.shape[1]):
        run = changes[:, axis] - 1
        first = np.searchsorted(run, run)  # the first sample of each sample's run
        others = np.delete(changes, axis, axis=1)
        varies = (others - others[first]).max(axis=1) > 0  # another axis changed in the run
        long_run = np.bincount(run)[run] > limit
        in_varying_run = np.bincount(run, weights=varies)[run] > 0
        stuck |= long_run & in_varying_run
    return stuck


def gyro_timeline(samples: GyroSamples, epochs: ArrayLike) -> GyroTimeline:
    """The steps of ``samples`` cut at ``epochs`` (module docstring).

    Raises:
        InvalidObservationError: epochs not increasing, or outside the record.
    """
    epochs = np.asarray(epochs, dtype=float).reshape(-1)
    t = np.asarray(samples.t, dtype=float)
    rates = np.asarray(samples.rates, dtype=float)
    dt = float(samples.dt)
    slack = COINCIDENCE * dt
    if epochs.size == 0 or np.any(np.diff(epochs) <= 0) or not np.all(np.isfinite(epochs)):
        raise InvalidObservationError("epochs must be finite and increasing")
    if epochs[0] < t[0] - slack or epochs[-1] > t[-1] + slack:
        raise InvalidObservationError(
            f"epochs {epochs[0]:g}-{epochs[-1]:g} s lie outside the gyro record "
            f"{t[0]:g}-{t[-1]:g} s"
        )
    nearest = np.clip(np.searchsorted(t, epochs - slack), 0, t.size - 1)
    on_sample = np.abs(t[nearest] - epochs) <= slack
    if on_sample.all():
        return GyroTimeline(t, rates, np.full(rates.shape[0], dt), nearest, True, dt)
    inserted = epochs[~on_sample]
    boundaries = np.concatenate([t, inserted])
    order = np.argsort(boundaries, kind="stable")
    boundaries = boundaries[order]
    # the sample whose interval each new step starts in
    sample = np.searchsorted(t, boundaries[:-1], side="right") - 1
    position = np.empty(order.size, dtype=np.intp)
    position[order] = np.arange(order.size)
    index = np.where(on_sample, nearest, 0)
    index[~on_sample] = position[t.size :]
    index[on_sample] = position[nearest[on_sample]]
    return GyroTimeline(
        boundaries, rates[sample], np.diff(boundaries), index.astype(np.intp), False, dt
    )
