"""A pass: epochs of measurements, an optional gyro record, dynamics and prior.

A :class:`Pass` is what a pass estimator (filter, smoother, batch least
squares; :mod:`attopt.solvers.registry`) consumes:

* ``t``: the epoch times (s), increasing;
* ``snapshots``: one :class:`~attopt.formulations.snapshot.Snapshot` (or
  ``None``: no measurement) per epoch;
* ``gyro``: a :class:`GyroRecord`, rate-integrating samples at any uniform
  rate with the :class:`~attopt.formulations.gyro.GyroModel` they follow.  The
  epochs need not be gyro sample times: the estimators propagate to each
  measurement time.  The record must cover the epochs;
* ``dynamics``: a :class:`RigidBody` (inertia, wheel momentum and the
  orbit frame at the epochs) for estimators that propagate Euler's equation
  instead of a gyro (Yang et al. 2014's EKF);
* ``prior``: a :class:`Prior` at the first epoch (or, with a gyro, at the
  first gyro sample).

Example::

    >>> import numpy as np
    >>> from attopt import GyroRecord, Pass
    >>> from attopt.formulations.gyro import MEMS_GYRO
    >>> t = np.arange(0.0, 10.0, 1.0) + 0.05  # not on the 10 Hz gyro's sample times
    >>> gyro = GyroRecord(np.arange(0.0, 10.01, 0.1), np.zeros((100, 3)), MEMS_GYRO)
    >>> body = reference = np.tile(np.eye(3)[:2], (10, 1, 1))
    >>> Pass.from_vectors(t, body, reference, sigma=1e-3, gyro=gyro)
    Pass(10 epochs, t 0.05-9.05 s, 10 with measurements, gyro mems at 10 Hz)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import GyroRateMismatchError, InvalidObservationError
from attopt.formulations.gyro import GyroModel, GyroSamples
from attopt.formulations.snapshot import Snapshot, snapshots_of

Array = NDArray[np.float64]

RATE_TOLERANCE = 1e-6
"""Relative tolerance between the gyro's declared step and its sample spacing."""


@dataclass(frozen=True, eq=False)
class GyroRecord:
    """Rate-integrating gyro samples with their model (:mod:`attopt.formulations.gyro`).

    Attributes:
        t: ``(n,)`` sample times (s), uniform at ``1 / model.rate_hz``.
        rates: ``(n - 1, 3)`` mean measured rates over ``[t_j, t_{j+1})`` (rad/s);
            NaN rows are missing samples (gaps).
        model: the noise and bias model the samples follow.

    Raises:
        GyroRateMismatchError: the sample spacing is not the model's declared step.
        InvalidObservationError: wrong shapes or times.

    Example::

        >>> import numpy as np
        >>> from attopt import MEMS_GYRO, GyroRateMismatchError, GyroRecord
        >>> record = GyroRecord(np.arange(11) / 10.0, np.zeros((10, 3)), MEMS_GYRO)  # 10 Hz
        >>> try:
        ...     GyroRecord(np.arange(21) / 20.0, np.zeros((20, 3)), MEMS_GYRO)  # 20 Hz samples
        ... except GyroRateMismatchError as error:
        ...     print(error)
        gyro 'mems' is declared at 10 Hz (step 0.1 s) but its samples are 0.05-0.05 s apart
    """

    t: Array
    rates: Array
    model: GyroModel

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float)
        rates = np.array(self.rates, dtype=float)
        if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)):
            raise InvalidObservationError("gyro sample times must be finite, (n,) with n >= 2")
        if rates.shape != (t.size - 1, 3):
            raise InvalidObservationError(
                f"gyro rates must be (n - 1, 3) = ({t.size - 1}, 3) for {t.size} sample times, "
                f"got {rates.shape}"
            )
        step = np.diff(t)
        dt = self.model.dt
        if not np.allclose(step, dt, rtol=RATE_TOLERANCE, atol=0.0):
            raise GyroRateMismatchError(
                f"gyro {self.model.name!r} is declared at {self.model.rate_hz:g} Hz "
                f"(step {dt:g} s) but its samples are {step.min():g}-{step.max():g} s apart"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "rates", rates)

    @property
    def samples(self) -> GyroSamples:
        """The record as the filters' :class:`~attopt.formulations.gyro.GyroSamples`."""
        return GyroSamples(self.t, self.rates, self.model.dt)

    @classmethod
    def from_dataframe(cls, frame: pd.DataFrame, model: GyroModel) -> GyroRecord:
        """Samples from a frame with columns ``t, rate_x, rate_y, rate_z`` (s, rad/s).

        Row ``j`` holds the mean rate over ``[t_j, t_{j+1})``; the last row
        closes the record (its rates are not used).
        """
        missing = sorted({"t", "rate_x", "rate_y", "rate_z"} - set(frame.columns))
        if missing:
            raise InvalidObservationError(f"gyro frame lacks columns {missing}")
        rates = frame[["rate_x", "rate_y", "rate_z"]].to_numpy(dtype=float)
        return cls(frame["t"].to_numpy(dtype=float), rates[:-1], model)


@dataclass(frozen=True)
class Prior:
    """An initial estimate and its covariance.

    Attributes:
        attitude: ``A`` (reference -> body).
        covariance: ``(3, 3)`` of the body-frame attitude error (rad^2), or
            ``(6, 6)`` of ``[attitude error, bias]`` (with ``bias``) or of
            ``[attitude error, rate]`` (with ``rate``).
        bias: ``(3,)`` gyro bias estimate (rad/s) for gyro-aided estimators.
        rate: ``(3,)`` body rate relative to inertial space (rad/s, body axes)
            for dynamics-based estimators.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import Prior
        >>> prior = Prior(Rotation.identity(), np.radians(5.0) ** 2 * np.eye(3))
        >>> with_bias = prior.with_bias_covariance(1e-3)  # zero bias, 1e-3 rad/s per axis
        >>> np.degrees(np.sqrt(np.diag(with_bias.covariance))).round(3).tolist()
        [5.0, 5.0, 5.0, 0.057, 0.057, 0.057]
    """

    attitude: Rotation
    covariance: Array
    bias: Array | None = None
    rate: Array | None = None

    def __post_init__(self) -> None:
        covariance = np.array(self.covariance, dtype=float)
        extra = self.bias if self.bias is not None else self.rate
        size = 3 if extra is None else 6
        if self.bias is not None and self.rate is not None:
            raise InvalidObservationError("a prior has a bias or a rate, not both")
        if covariance.shape != (size, size) or not np.all(np.isfinite(covariance)):
            raise InvalidObservationError(f"prior covariance must be finite, ({size}, {size})")
        if extra is not None and (np.shape(extra) != (3,) or not np.all(np.isfinite(extra))):
            raise InvalidObservationError("prior bias or rate must be a finite (3,) vector")
        if not np.allclose(covariance, covariance.T) or np.linalg.eigvalsh(covariance)[0] <= 0:
            raise InvalidObservationError("prior covariance must be symmetric positive definite")
        if not np.all(np.isfinite(self.attitude.as_quat())):
            raise InvalidObservationError("prior attitude must be finite")
        object.__setattr__(self, "covariance", covariance)

    def with_bias_covariance(self, bias_sigma: float) -> Prior:
        """The ``[attitude, bias]`` prior with zero bias and ``bias_sigma`` (rad/s) per axis,
        for a gyro-aided estimator given an attitude-only prior."""
        if self.covariance.shape == (6, 6):
            return self
        covariance = np.zeros((6, 6))
        covariance[:3, :3] = self.covariance
        covariance[3:, 3:] = bias_sigma**2 * np.eye(3)
        return Prior(self.attitude, covariance, bias=np.zeros(3))


@dataclass(frozen=True, eq=False)
class RigidBody:
    """Known rigid-body dynamics of a pass (Yang et al. 2014, eqs. 23-25).

    Attributes:
        inertia: ``(3, 3)`` inertia matrix (kg m^2, body axes).
        orbit_frames: ``A_oi`` (inertial -> orbit) at the epochs; the attitude
            estimated is ``C_bo`` (orbit -> body).
        wheel_momentum: ``(3,)`` or ``(N, 3)`` reaction-wheel momentum (N m s, body).

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import RigidBody
        >>> frames = Rotation.from_rotvec(np.outer(np.arange(4), [0.0, -1e-3, 0.0]))  # A_oi
        >>> body = RigidBody(np.diag([6.6, 8.9, 9.5]), frames)
        >>> body.orbit_turns.magnitude().round(6).tolist()
        [0.001, 0.001, 0.001]
    """

    inertia: Array
    orbit_frames: Rotation
    wheel_momentum: Array = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        inertia = np.array(self.inertia, dtype=float)
        if inertia.shape != (3, 3) or not np.allclose(inertia, inertia.T):
            raise InvalidObservationError("inertia must be a symmetric (3, 3) matrix")
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "wheel_momentum", np.array(self.wheel_momentum, dtype=float))

    @property
    def orbit_turns(self) -> Rotation:
        """``O_{k+1} O_k^T`` between consecutive epochs (``N - 1`` rotations)."""
        return self.orbit_frames[1:] * self.orbit_frames[:-1].inv()


@dataclass(frozen=True, eq=False)
class Pass:
    """Epochs of measurements with an optional gyro record, dynamics and prior (module docstring).

    Raises:
        InvalidObservationError: epochs not increasing or not covered by the
            gyro record, or lengths that do not match.

    Example::

        >>> import numpy as np
        >>> from attopt import MEMS_GYRO, GyroRecord, Pass
        >>> gyro = GyroRecord(np.arange(51) / 10.0, np.zeros((50, 3)), MEMS_GYRO)
        >>> directions = np.eye(3)[:2]
        >>> body = np.tile(directions, (3, 1, 1))
        >>> Pass.from_vectors([0.25, 1.25, 2.25], body, directions, 1e-3, gyro)
        Pass(3 epochs, t 0.25-2.25 s, 3 with measurements, gyro mems at 10 Hz)
    """

    t: Array
    snapshots: tuple[Snapshot | None, ...]
    gyro: GyroRecord | None = None
    prior: Prior | None = None
    dynamics: RigidBody | None = None

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float).reshape(-1)
        snapshots = tuple(snapshots_of(self.snapshots))
        if t.size == 0 or len(snapshots) != t.size:
            raise InvalidObservationError(f"{len(snapshots)} snapshots for {t.size} epochs")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise InvalidObservationError("epoch times must be finite and increasing")
        if self.gyro is not None:
            g = self.gyro.t
            slack = 1e-6 * self.gyro.model.dt
            if t[0] < g[0] - slack or t[-1] > g[-1] + slack:
                raise InvalidObservationError(
                    f"the gyro record ({g[0]:g}-{g[-1]:g} s) must cover the epochs "
                    f"({t[0]:g}-{t[-1]:g} s)"
                )
        if self.dynamics is not None and len(self.dynamics.orbit_frames) != t.size:
            raise InvalidObservationError("the dynamics need one orbit frame per epoch")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "snapshots", snapshots)

    def __len__(self) -> int:
        return self.t.size

    @classmethod
    def from_measurements(
        cls,
        t: ArrayLike,
        measurements: Sequence[AttitudeMeasurement | Snapshot | None],
        gyro: GyroRecord | None = None,
        prior: Prior | None = None,
        dynamics: RigidBody | None = None,
    ) -> Pass:
        """One measurement (or snapshot, or ``None``: none) per epoch ``t``."""
        return cls(t, epoch_snapshots(measurements, t), gyro, prior, dynamics)

    @classmethod
    def from_vectors(
        cls,
        t: ArrayLike,
        body: ArrayLike,
        reference: ArrayLike,
        sigma: ArrayLike,
        gyro: GyroRecord | None = None,
        prior: Prior | None = None,
    ) -> Pass:
        """Unit-vector pairs per epoch: ``body`` ``(N, k, 3)`` (NaN rows: absent),
        ``reference`` ``(N, k, 3)`` or, for fixed directions, ``(k, 3)``, ``sigma``
        broadcastable to ``(N, k)`` (rad)."""
        t = np.asarray(t, dtype=float)
        body = np.asarray(body, dtype=float)
        if body.ndim != 3 or body.shape[0] != t.size or body.shape[2] != 3:
            raise InvalidObservationError("body vectors must be (N, k, 3) for N epochs")
        try:
            reference = np.broadcast_to(np.asarray(reference, dtype=float), body.shape)
        except ValueError:
            raise InvalidObservationError(
                f"reference vectors must be (N, k, 3) or (k, 3) for body {body.shape}"
            ) from None
        sigma = np.broadcast_to(np.asarray(sigma, dtype=float), body.shape[:2])
        snapshots = [_vector_snapshot(body[k], reference[k], sigma[k], t[k]) for k in range(t.size)]
        return cls(t, tuple(snapshots), gyro, prior)

    @classmethod
    def from_dataframe(
        cls,
        vectors: pd.DataFrame,
        gyro: GyroRecord | None = None,
        prior: Prior | None = None,
    ) -> Pass:
        """Unit-vector measurements from a long frame: one row per vector with columns
        ``t``, :data:`~attopt.formulations.snapshot.VECTOR_COLUMNS` and ``sigma``; rows
        sharing ``t`` form one epoch."""
        if "t" not in vectors:
            raise InvalidObservationError("vector frame lacks column 't'")
        groups = vectors.sort_values("t", kind="stable").groupby("t", sort=True)
        t = np.array([time for time, _ in groups], dtype=float)
        snapshots = tuple(Snapshot.from_dataframe(rows, t=time) for time, rows in groups)
        return cls(t, snapshots, gyro, prior)

    def measurements(self) -> list[AttitudeMeasurement | None]:
        """One measurement per epoch (each snapshot's parts stacked), ``None`` where absent."""
        return [None if s is None else s.measurement() for s in self.snapshots]

    def types(self) -> frozenset[type[AttitudeMeasurement]]:
        """Every measurement class in the pass (found once: a pass does not change, and
        every estimator checks them)."""
        return self._types

    @cached_property
    def _types(self) -> frozenset[type[AttitudeMeasurement]]:
        return frozenset().union(*(s.types for s in self.snapshots if s is not None))

    def __repr__(self) -> str:
        n = len(self)
        measured = sum(s is not None for s in self.snapshots)
        parts = [
            f"{n} epochs",
            f"t {self.t[0]:g}-{self.t[-1]:g} s",
            f"{measured} with measurements",
        ]
        if self.gyro is not None:
            parts.append(f"gyro {self.gyro.model.name} at {self.gyro.model.rate_hz:g} Hz")
        if self.dynamics is not None:
            parts.append("rigid-body dynamics")
        if self.prior is not None:
            parts.append("prior")
        return f"Pass({', '.join(parts)})"


def _vector_snapshot(body: Array, reference: Array, sigma: Array, t: float) -> Snapshot | None:
    present = np.isfinite(body).all(axis=1) & np.isfinite(reference).all(axis=1)
    if not present.any():
        return None
    return Snapshot.from_vectors(body[present], reference[present], sigma[present], t=t)


def epoch_snapshots(
    measurements: Sequence[AttitudeMeasurement | Snapshot | None], t: ArrayLike
) -> tuple[Snapshot | None, ...]:
    """Snapshots with their epoch times from per-epoch measurements (``None``: none)."""
    t = np.asarray(t, dtype=float)
    out = []
    for k, item in enumerate(snapshots_of(measurements)):
        out.append(None if item is None else Snapshot(item.measurements, float(t[k])))
    return tuple(out)
