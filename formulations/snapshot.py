"""A snapshot: one epoch's measurements of any mix of types, each with its noise model.

A :class:`Snapshot` holds :class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement`
objects (unit vectors, SNRs, DOAs, Euler angles, or a type of your own) taken
at one time.  Snapshot estimators (:mod:`attopt.solvers.registry`) solve it
for the attitude; a :class:`~attopt.formulations.passes.Pass` is a sequence
of them with an optional gyro record.  Filters and smoothers see a snapshot
as one measurement, :meth:`Snapshot.measurement`: its parts stacked
(:class:`StackedMeasurement`), each part keeping its own model, noise and
innovation.

Example::

    >>> from attopt import Snapshot
    >>> snapshot = Snapshot.from_vectors(
    ...     body=[[1, 0, 0], [0, 1, 0]], reference=[[1, 0, 0], [0, 1, 0]], sigma=[1e-3, 2e-3]
    ... )
    >>> snapshot
    Snapshot(t=nan, VectorMeasurement x 1: 6 rows)
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike
from scipy.linalg import block_diag
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    Array,
    AttitudeMeasurement,
    VectorMeasurement,
)
from attopt.formulations.errors import InvalidObservationError

VECTOR_COLUMNS = ("body_x", "body_y", "body_z", "reference_x", "reference_y", "reference_z")
"""Columns of a vector-measurement frame (:meth:`Snapshot.from_dataframe`), besides ``sigma``."""


def _combined_noise(parts: Sequence[Array]) -> Array:
    """Noise covariances of stacked parts: variances stay variances, else block diagonal."""
    if all(p.ndim == 1 for p in parts):
        return np.concatenate(parts) if parts else np.zeros(0)
    return block_diag(*(np.diag(p) if p.ndim == 1 else p for p in parts))


class StackedMeasurement(AttitudeMeasurement):
    """Several measurements of one epoch as one: rows, noise and blocks stacked in order.

    Predictions, Jacobians and innovations are each part's own, so a filter or
    smoother that consumes one measurement per epoch consumes any mix.  Parts
    are independent (block-diagonal ``R``).  Transmitter offsets (``sources``)
    are kept only when every part has them.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import EulerAngleMeasurement, Snapshot, VectorMeasurement
        >>> sun = VectorMeasurement([[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], 1e-3)
        >>> angles = EulerAngleMeasurement([0.0, 0.0, 0.0], 1e-4 * np.eye(3))
        >>> stacked = Snapshot.of(sun, angles).measurement()
        >>> stacked.size, stacked.predict(Rotation.identity())[1].shape
        (6, (1, 6, 3))
    """

    def __init__(self, parts: Sequence[AttitudeMeasurement]) -> None:
        self.parts = tuple(parts)
        sizes = [p.size for p in self.parts]
        self._bounds = np.cumsum([0, *sizes])
        self.z = np.concatenate([p.z for p in self.parts]) if self.parts else np.zeros(0)
        self.noise_covariance = _combined_noise(
            [np.asarray(p.noise_covariance) for p in self.parts]
        )
        offsets = np.cumsum([0, *(int(p.blocks.max()) + 1 if p.size else 0 for p in self.parts)])
        self.blocks = np.concatenate(
            [p.blocks + o for p, o in zip(self.parts, offsets, strict=False)]
        ).astype(np.intp)
        if self.parts and all(p.sources is not None for p in self.parts):
            self.sources = np.concatenate([p.sources for p in self.parts])

    def _split(self, x: Array) -> list[Array]:
        return [x[..., a:b] for a, b in zip(self._bounds[:-1], self._bounds[1:], strict=True)]

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        outputs = [p.predict(attitude, jacobian) for p in self.parts]
        h = np.concatenate([o[0] for o in outputs], axis=-1)
        if not jacobian:
            return h, None
        return h, np.concatenate([o[1] for o in outputs], axis=-2)

    def innovation(self, predicted: Array) -> Array:
        parts = self._split(predicted)
        return np.concatenate([p.innovation(x) for p, x in zip(self.parts, parts, strict=True)], -1)

    def noise_covariance_at(self, attitude: Rotation) -> Array:
        return _combined_noise([np.asarray(p.noise_covariance_at(attitude)) for p in self.parts])

    def with_offsets(self, offsets: Array) -> StackedMeasurement:
        parts = self._split(np.asarray(offsets, dtype=float))
        return StackedMeasurement(
            [p.with_offsets(o) for p, o in zip(self.parts, parts, strict=True)]
        )

    def offset_slope(self, attitude: Rotation) -> Array:
        return np.concatenate([p.offset_slope(attitude) for p in self.parts])


@dataclass(frozen=True, eq=False)
class Snapshot:
    """One epoch's measurements (module docstring).

    Attributes:
        measurements: the epoch's measurements, of any
            :class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement` types.
        t: the epoch's time (s); NaN when not given.

    Example::

        >>> import numpy as np
        >>> from attopt import EulerAngleMeasurement, Snapshot, VectorMeasurement
        >>> sun = VectorMeasurement([[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], 1e-3)
        >>> angles = EulerAngleMeasurement([0.0, 0.0, 0.0], 1e-4 * np.eye(3))
        >>> Snapshot.of(sun, angles, t=12.0)
        Snapshot(t=12, VectorMeasurement x 1, EulerAngleMeasurement x 1: 6 rows)
    """

    measurements: tuple[AttitudeMeasurement, ...]
    t: float = np.nan

    def __post_init__(self) -> None:
        measurements = tuple(self.measurements)
        bad = [type(m).__name__ for m in measurements if not isinstance(m, AttitudeMeasurement)]
        if bad:
            raise InvalidObservationError(
                f"a snapshot holds AttitudeMeasurement objects, not {', '.join(bad)}"
            )
        object.__setattr__(self, "measurements", measurements)
        object.__setattr__(self, "t", float(self.t))

    @classmethod
    def of(cls, *measurements: AttitudeMeasurement, t: float = np.nan) -> Snapshot:
        """The snapshot of ``measurements`` at time ``t``."""
        return cls(measurements, t)

    @classmethod
    def from_vectors(
        cls,
        body: ArrayLike,
        reference: ArrayLike,
        sigma: ArrayLike | None = None,
        covariance: ArrayLike | None = None,
        t: float = np.nan,
    ) -> Snapshot:
        """Unit-vector pairs ``b_i = A r_i + noise`` (``(k, 3)`` each) with per-vector
        ``sigma`` (rad, scalar or ``(k,)``) or ``covariance`` (``(k, 3, 3)``, rad^2);
        :class:`~attopt.formulations.attitude_measurement.VectorMeasurement`."""
        return cls((VectorMeasurement(body, reference, sigma, covariance),), t)

    @classmethod
    def from_dataframe(cls, frame: pd.DataFrame, t: float | None = None) -> Snapshot:
        """Vector pairs from a frame with columns :data:`VECTOR_COLUMNS` and ``sigma`` (rad),
        one row per vector; ``t`` defaults to the frame's ``t`` column if it has one."""
        missing = sorted(set((*VECTOR_COLUMNS, "sigma")) - set(frame.columns))
        if missing:
            raise InvalidObservationError(f"vector frame lacks columns {missing}")
        if t is None:
            times = np.unique(frame["t"]) if "t" in frame else np.array([np.nan])
            if times.size != 1:
                raise InvalidObservationError(
                    f"a snapshot has one time, the frame has {times.size}"
                )
            t = float(times[0])
        values = frame[list(VECTOR_COLUMNS)].to_numpy(dtype=float)
        return cls.from_vectors(values[:, :3], values[:, 3:], frame["sigma"].to_numpy(float), t=t)

    def measurement(self) -> AttitudeMeasurement:
        """The snapshot as one measurement: the only one, or all of them stacked."""
        if len(self.measurements) == 1:
            return self.measurements[0]
        return StackedMeasurement(self.measurements)

    def of_type(self, kind: type[AttitudeMeasurement]) -> list[AttitudeMeasurement]:
        """The measurements that are instances of ``kind``."""
        return [m for m in self.measurements if isinstance(m, kind)]

    @property
    def types(self) -> frozenset[type[AttitudeMeasurement]]:
        """The measurement classes present."""
        return frozenset(type(m) for m in self.measurements)

    @property
    def size(self) -> int:
        """Rows over all measurements."""
        return sum(m.size for m in self.measurements)

    def __repr__(self) -> str:
        counts = Counter(type(m).__name__ for m in self.measurements)
        kinds = ", ".join(f"{name} x {n}" for name, n in counts.items()) or "empty"
        return f"Snapshot(t={self.t:g}, {kinds}: {self.size} rows)"


def snapshots_of(items: Iterable[Snapshot | AttitudeMeasurement | None]) -> list[Snapshot | None]:
    """Snapshots of a sequence of snapshots, single measurements or ``None`` (no measurement)."""
    out: list[Snapshot | None] = []
    for item in items:
        if item is None or isinstance(item, Snapshot):
            out.append(item)
        elif isinstance(item, AttitudeMeasurement):
            out.append(Snapshot((item,)))
        else:
            raise InvalidObservationError(
                f"expected a Snapshot, an AttitudeMeasurement or None, not {type(item).__name__}"
            )
    return out
