"""The measurement interface every attitude filter and smoother consumes.

An :class:`AttitudeMeasurement` is one epoch's measurement vector ``z`` (``m``
rows) with its noise covariance ``R`` and a model ``h(A)`` of the attitude
``A`` (reference -> body, ``docs/conventions.md``).  :meth:`~AttitudeMeasurement.predict`
returns ``h`` at a stack of attitudes and its Jacobian with respect to the
body-frame attitude error ``delta`` of ``exp(delta) A`` at ``delta = 0``; the
filters (``solvers/filters``) and the factor-graph smoother use nothing else,
so they contain no measurement-specific code.  Rows are grouped in blocks
(one observation each: one SNR, one unit vector, one Euler-angle triple) for
outlier gating.

Symbolic models are written once with :mod:`attopt.formulations.symbolic` and
differentiated by CasADi
(:func:`attopt.formulations.attitude_model.attitude_model_function`): the attitude
enters as ``C(v) A`` (:func:`attopt.formulations.attitude_model.increment_matrix`,
Liu et al. 2023 eq. 28), whose derivative at ``v = 0`` is the body-frame Jacobian.
:meth:`AttitudeMeasurement.symbolic` returns that model with its parameter
values and its symbolic innovation
(:class:`~attopt.formulations.measurement_model.SymbolicModel`); the default
:meth:`~AttitudeMeasurement.predict` and :meth:`~AttitudeMeasurement.innovation`
evaluate it, so a new measurement type only writes :meth:`~AttitudeMeasurement.symbolic`,
and the generic estimators (the MAP NLP, :mod:`attopt.solvers.map_nlp`, and
the Cramer-Rao bound, :mod:`attopt.solvers.bounds`) use it as well.  The
types below keep their own ``predict`` where it has a faster numpy path or
masks unpredictable rows; their AD values and Jacobians come from the same
symbolic model.

Implementations: :class:`EulerAngleMeasurement` (Liu et al. 2023 eqs. 41-46, the
"paper MEKF" observation), :class:`VectorMeasurement` (unit vectors, Cilden Guler et
al. 2017 eqs. 2-4), :class:`attopt.formulations.snr_measurement.SnrMeasurement`
(SNRs, Liu et al. 2023 eq. 13); :class:`ReferencedMeasurement` re-expresses any of
them for an attitude relative to another reference frame.
"""

from __future__ import annotations

from abc import ABC
from collections.abc import Callable, Hashable, Sequence
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import block_diag
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_model import evaluate_at_attitudes
from attopt.formulations.conventions import euler321_from_attitude
from attopt.formulations.errors import InvalidObservationError, UnsupportedMeasurementError
from attopt.formulations.geodesic import geodesic_reference, geodesic_rows
from attopt.formulations.kernels import compiled_loops
from attopt.formulations.measurement_model import (
    SymbolicModel,
    difference,
    geodesic_difference,
    wrapped_difference,
)
from attopt.formulations.symbolic import CASADI

Array = NDArray[np.float64]


class AttitudeMeasurement(ABC):
    """One epoch's measurement ``z = h(A) + noise``, ``noise ~ N(0, R)``.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import AttitudeMeasurement, SymbolicModel
        >>> def boresight_z(attitude, reference):  # a type of your own: z of A r, in one function
        ...     return (attitude @ reference)[2]
        >>> class Boresight(AttitudeMeasurement):
        ...     def __init__(self, value, reference, sigma):
        ...         self.z = np.atleast_1d(float(value))
        ...         self.reference = np.asarray(reference, float)
        ...         self.noise_covariance, self.blocks = np.array([sigma**2]), np.zeros(1, int)
        ...     def symbolic(self):
        ...         return SymbolicModel(boresight_z, (self.reference,))
        >>> h, jacobian = Boresight(1.0, [0.0, 0.0, 1.0], 1e-3).predict(Rotation.identity())
        >>> h.tolist(), (jacobian.round(12) + 0.0).tolist()
        ([[1.0]], [[[0.0, 0.0, 0.0]]])
    """

    z: Array
    """``(m,)`` measured values."""
    noise_covariance: Array
    """``R``: ``(m,)`` variances of independent rows, or an ``(m, m)`` matrix."""
    blocks: NDArray[np.intp]
    """``(m,)`` block index of each row (rows of one observation share a block)."""

    @property
    def size(self) -> int:
        return int(self.z.shape[0])

    def symbolic(self) -> SymbolicModel:
        """The model ``h(A)`` written symbolically, with its parameter values and innovation.

        Types without one raise
        :class:`~attopt.formulations.errors.UnsupportedMeasurementError`
        (they must then implement :meth:`predict`); the generic estimators
        accept only types that have one.
        """
        raise UnsupportedMeasurementError(f"{type(self).__name__} has no symbolic model")

    def symbolic_model(self) -> SymbolicModel:
        """:meth:`symbolic`, built once per measurement (not pickled: models may be closures)."""
        model = self.__dict__.get("_symbolic_model")
        if model is None:
            model = self.__dict__["_symbolic_model"] = self.symbolic()
        return model

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state.pop("_symbolic_model", None)
        return state

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        """Predictions ``(N, m)`` and Jacobians ``(N, m, 3)`` at ``N`` stacked attitudes.

        Rows the model cannot evaluate at some of the attitudes (for example an
        observation outside the antenna's main lobe) are NaN for every attitude.
        With ``jacobian=False`` the Jacobian is ``None`` (sigma-point filters)
        and types with a numpy evaluation of their model use it.  By default
        both come from :meth:`symbolic` by CasADi AD.
        """
        h, jac = self.symbolic_model().evaluate(attitude)
        return h, (jac if jacobian else None)

    def batch_key(self) -> Hashable | None:
        """Measurements of one class with equal keys are predicted together, in one call
        into their model's kernel (:meth:`predict_batch`, :func:`predict_each`); ``None``
        (the default): one :meth:`predict` each."""
        return None

    @classmethod
    def predict_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[tuple[Array, Array]]:
        """``[m.predict(attitudes[i]) for i, m in enumerate(measurements)]`` for measurements
        of this class with one :meth:`batch_key`; the types that give a key override it
        with a single evaluation, equal to the loop bit for bit."""
        return [m.predict(attitudes[i]) for i, m in enumerate(measurements)]

    @classmethod
    def noise_covariance_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[Array]:
        """``[m.noise_covariance_at(attitudes[i]) for ...]`` for measurements of this class
        with one :meth:`batch_key` (types whose ``R`` depends on the attitude override it;
        for the others no attitude is looked at)."""
        if not _noise_depends_on_attitude(cls):
            return [m.noise_covariance for m in measurements]
        return [m.noise_covariance_at(attitudes[i]) for i, m in enumerate(measurements)]

    def innovation(self, predicted: Array) -> Array:
        """``z - h`` for predictions ``(..., m)`` (angles wrapped where the model has them).

        By default the innovation of :meth:`symbolic`, evaluated on the arrays.
        """
        if type(self).symbolic is AttitudeMeasurement.symbolic:
            return self.z - predicted
        model = self.symbolic_model()
        if model.innovation is difference:
            return self.z - predicted
        return model.innovation_values(self.z, predicted)

    def noise_covariance_at(self, attitude: Rotation) -> Array:
        """``R`` at an attitude (models whose noise depends on it override this)."""
        return self.noise_covariance

    sources: NDArray[np.intp] | None = None
    """``(m,)`` identifier of the unknown additive offset inside each row's model (a
    transmitter's power offset, dB: ``docs/smoother.md``), or ``None`` for models without one."""

    def with_offsets(self, offsets: Array) -> AttitudeMeasurement:
        """The measurement whose model adds ``offsets`` ``(m,)`` to its rows' offset parameter."""
        raise InvalidObservationError(f"{type(self).__name__} has no offset parameters")

    def offset_slope(self, attitude: Rotation) -> Array:
        """``dh / d offset`` ``(m,)`` of each row at one attitude (CasADi AD)."""
        raise InvalidObservationError(f"{type(self).__name__} has no offset parameters")

    @classmethod
    def offset_slope_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[Array]:
        """``[m.offset_slope(attitudes[i]) for ...]`` for measurements of this class with one
        :meth:`batch_key` (types with offsets override it with a single evaluation)."""
        return [m.offset_slope(attitudes[i]) for i, m in enumerate(measurements)]

    def with_offset_spread(self, spread: float) -> AttitudeMeasurement:
        """The measurement with its rows' offsets unknown, ``N(0, spread^2)`` each and
        independent: their noise widened accordingly."""
        raise InvalidObservationError(f"{type(self).__name__} has no offset parameters")


def predict_each(
    measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
) -> list[tuple[Array, Array]]:
    """Each measurement's prediction and Jacobian at its own attitude, as
    ``[m.predict(attitudes[i]) for i, m in enumerate(measurements)]`` computes them, with the
    measurements that share a class and a :meth:`~AttitudeMeasurement.batch_key` evaluated
    together (:meth:`~AttitudeMeasurement.predict_batch`): a pass's epochs of unit vectors or
    SNRs cost one kernel call, not one per epoch.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import VectorMeasurement
        >>> r = np.eye(3)[:2]
        >>> attitudes = Rotation.from_rotvec([[0.0, 0.0, 0.1], [0.2, 0.0, 0.0]])
        >>> ms = [VectorMeasurement(a.apply(r), r, 1e-3) for a in attitudes]
        >>> [(h.shape, j.shape) for h, j in predict_each(ms, attitudes)]
        [((1, 6), (1, 6, 3)), ((1, 6), (1, 6, 3))]
    """
    return _each(measurements, attitudes, "predict_batch", lambda m, a: m.predict(a))


def noise_covariance_each(
    measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
) -> list[Array]:
    """``[m.noise_covariance_at(attitudes[i]) for ...]``, grouped as :func:`predict_each`
    (:meth:`~AttitudeMeasurement.noise_covariance_batch`)."""
    return _each(
        measurements, attitudes, "noise_covariance_batch", lambda m, a: m.noise_covariance_at(a)
    )


def offset_slope_each(
    measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
) -> list[Array]:
    """``[m.offset_slope(attitudes[i]) for ...]``, grouped as :func:`predict_each`
    (:meth:`~AttitudeMeasurement.offset_slope_batch`)."""
    return _each(measurements, attitudes, "offset_slope_batch", lambda m, a: m.offset_slope(a))


def _each(
    measurements: Sequence[AttitudeMeasurement],
    attitudes: Rotation,
    batch: str,
    alone: Callable[[AttitudeMeasurement, Rotation], Any],
) -> list[Any]:
    """``alone(m, attitudes[i])`` per measurement, those sharing a class and a batch key by
    one call of the class's method ``batch``."""
    results: list[Any] = [None] * len(measurements)
    groups: dict[tuple[type, Hashable], list[int]] = {}
    for i, measurement in enumerate(measurements):
        key = measurement.batch_key()
        if key is None:
            results[i] = alone(measurement, attitudes[i])
        else:
            groups.setdefault((type(measurement), key), []).append(i)
    for (cls, _), index in groups.items():
        values = getattr(cls, batch)([measurements[i] for i in index], attitudes[index])
        for i, value in zip(index, values, strict=True):
            results[i] = value
    return results


def symbolic_predict_batch(
    measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
) -> list[tuple[Array, Array]]:
    """:meth:`AttitudeMeasurement.predict` of measurements with one symbolic model structure
    (:attr:`~attopt.formulations.measurement_model.SymbolicModel.structure`), each at its
    attitude, in one kernel call: their parameters stacked on a leading axis."""
    models = [m.symbolic_model() for m in measurements]
    parameters = [np.stack(values) for values in zip(*(m.parameters for m in models), strict=True)]
    h, jacobian = evaluate_at_attitudes(models[0].function, attitudes.as_matrix(), *parameters)
    if models[0].rows is not None:
        rows = list(models[0].rows)
        h, jacobian = h[:, rows], jacobian[:, rows]
    return [(h[i : i + 1], jacobian[i : i + 1]) for i in range(len(measurements))]


def _check_vector(name: str, value: ArrayLike) -> Array:
    a = np.array(value, dtype=float)
    if a.ndim != 1:
        raise InvalidObservationError(f"{name} must be one-dimensional, got shape {a.shape}")
    return a


def euler321_model(attitude: Any) -> Any:
    """``[yaw, pitch, roll]`` of Liu et al. 2023 eq. 8 from the attitude matrix (symbolic).

    ``A = R1(roll) R2(pitch) R3(yaw)`` has ``A12 / A11 = tan(yaw)``,
    ``A13 = -sin(pitch)``, ``A23 / A33 = tan(roll)``; pitch is taken as
    ``atan2(-A13, sqrt(A11^2 + A12^2))``, well conditioned away from +/-90 deg.
    """
    xp = CASADI
    a = [[xp.entry(attitude, i, j) for j in range(3)] for i in range(3)]
    yaw = xp.atan2(a[0][1], a[0][0])
    pitch = xp.atan2(-a[0][2], xp.sqrt(a[0][0] ** 2 + a[0][1] ** 2))
    roll = xp.atan2(a[1][2], a[2][2])
    return ca.vertcat(yaw, pitch, roll)


def _wrap(angle: Array) -> Array:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


class EulerAngleMeasurement(AttitudeMeasurement):
    """3-2-1 Euler angles of an attitude solution as a measurement (Liu et al. 2023 eqs. 41-46).

    ``z = [yaw, pitch, roll]`` (rad) of a single-frame solution (the paper uses
    the NLSE's); the Jacobian (AD) equals minus Liu et al. 2023 eq. 44's ``H_v``, the
    Euler-rate kinematics matrix at the predicted angles: the paper's error
    vector is the opposite rotation of attopt's ``delta`` (its eq. 36 has
    ``- delta_beta``, see :mod:`attopt.formulations.gyro`).  One gating block.

    Example::

        >>> import numpy as np
        >>> from attopt import EulerAngleMeasurement, Snapshot, attitude_from_euler321, estimator
        >>> angles = np.radians([30.0, -10.0, 5.0])  # yaw, pitch, roll
        >>> measured = EulerAngleMeasurement(angles, np.radians(1.0) ** 2 * np.eye(3))
        >>> solution = estimator("map_nlp").solve(Snapshot.of(measured))
        >>> error = solution.attitude * attitude_from_euler321(*angles).inv()
        >>> bool(error.magnitude() < 1e-9)
        True
    """

    def __init__(self, angles: ArrayLike, covariance: ArrayLike) -> None:
        self.z = _check_vector("angles", angles)
        self.noise_covariance = np.array(covariance, dtype=float)
        if self.z.shape != (3,) or self.noise_covariance.shape != (3, 3):
            raise InvalidObservationError("Euler angles must be (3,) with a (3, 3) covariance")
        self.blocks = np.zeros(3, dtype=np.intp)

    def symbolic(self) -> SymbolicModel:
        """:func:`euler321_model`; every angle's difference is wrapped."""
        return SymbolicModel(
            euler321_model, innovation=wrapped_difference, innovation_parameters=(np.ones(3),)
        )

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        if not jacobian:
            return euler321_from_attitude(attitude).reshape(-1, 3), None
        return super().predict(attitude)

    def innovation(self, predicted: Array) -> Array:
        return _wrap(self.z - predicted)


def body_vectors_model(attitude: Any, reference: Any) -> Any:
    """``b_i = A r_i`` stacked as ``[b_1; b_2; ...]`` (Cilden Guler et al. 2017 eqs. 2, 4;
    symbolic)."""
    return ca.vec(attitude @ reference.T)


class VectorMeasurement(AttitudeMeasurement):
    """Measured body-frame unit vectors ``b_i = A r_i + noise`` (Cilden Guler et al. 2017 eqs. 2-4).

    ``z`` is the ``k`` measured vectors stacked (``3 k`` rows); each vector is a
    gating block and rows with a NaN vector are dropped.  The noise is given
    per vector either as a standard deviation ``sigma_i`` (rad), ``R_i =
    sigma_i^2 I3``, the QUEST measurement model of Cilden Guler et al. 2017 sec. 2.3, or as a
    positive-definite ``3 x 3`` covariance ``C_i`` (rad^2), then ``R`` is block
    diagonal with the ``C_i``.  :attr:`sigma` is each vector's isotropic
    equivalent, ``sigma_i^2 = tr(P_i C_i P_i) / 2`` with ``P_i = I - b_i
    b_i^T`` (the mean variance perpendicular to the measured direction; the
    component along it does not move the attitude to first order), which is
    ``sigma_i`` itself for ``C_i = sigma_i^2 I3``: the weight ``1 / sigma_i^2``
    of Wahba's problem (Cilden Guler et al. 2017 eq. 14).

    The innovation of each vector is its geodesic difference in the plane
    perpendicular to the prediction ``h_i``: ``theta p / |p|`` with ``p`` the
    component of ``z_i`` perpendicular to ``h_i`` and ``theta`` the angle
    between them.  To first order it is ``z_i - h_i``; the raw difference also
    has a second-order part along ``h_i`` (``cos(theta) - 1``) that the linear
    model cannot explain (the Jacobian's rows are perpendicular to ``h_i``) and
    that, after a 20 deg initial error against ``sigma = 0.001``, would fail the
    gate; and a reversed vector gets ``theta = pi``, not zero (an exactly
    antipodal one is NaN: left out).  The innovation has two degrees of freedom
    per vector, so the gate (chi-square with three) is slightly lenient.

    Example::

        >>> import numpy as np
        >>> from attopt import VectorMeasurement
        >>> reference = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        >>> m = VectorMeasurement(reference, reference, covariance=np.diag([1e-6, 4e-6, 4e-6]))
        >>> m.sigma.round(4).tolist()  # each vector's isotropic equivalent (Wahba weight 1/sigma^2)
        [0.002, 0.0016]
    """

    def __init__(
        self,
        body: ArrayLike,
        reference: ArrayLike,
        sigma: ArrayLike | None = None,
        covariance: ArrayLike | None = None,
    ) -> None:
        if (sigma is None) == (covariance is None):
            raise InvalidObservationError("give the vectors' noise as sigma or as covariance")
        try:
            b = np.array(body, dtype=float).reshape(-1, 3)
            r = np.array(reference, dtype=float).reshape(-1, 3)
            if covariance is None:
                s = np.asarray(sigma, dtype=float)
                if s.shape != (b.shape[0],):
                    s = np.broadcast_to(s, (b.shape[0],))
            else:
                c = np.broadcast_to(np.asarray(covariance, dtype=float), (b.shape[0], 3, 3))
        except ValueError as exc:
            raise InvalidObservationError(
                f"vectors must be (k, 3) with k sigmas or (k, 3, 3) covariances: {exc}"
            ) from None
        if r.shape != b.shape:
            raise InvalidObservationError(f"body {b.shape} and reference {r.shape} differ")
        # ndarray methods, not np.all / np.repeat: a pass builds one of these per epoch
        keep = np.isfinite(b).all(axis=1) & np.isfinite(r).all(axis=1)
        if not keep.all():
            b, r = b[keep], r[keep]
        self.reference = r
        self.z = b.ravel()
        self.blocks = np.arange(b.shape[0]).repeat(3)
        if covariance is None:
            s = s[keep]
            if not ((s > 0.0) & (s < np.inf)).all():  # NaN fails both
                raise InvalidObservationError(
                    "vector standard deviations must be finite and positive"
                )
            self.sigma = s
            self.noise_covariance = (s**2).repeat(3)
            return
        c = c[keep]
        if not np.all(np.isfinite(c)) or not np.allclose(c, c.transpose(0, 2, 1)):
            raise InvalidObservationError("vector covariances must be finite and symmetric")
        if c.shape[0] and np.linalg.eigvalsh(c).min() <= 0:
            raise InvalidObservationError("vector covariances must be positive definite")
        unit = b / np.linalg.norm(b, axis=1, keepdims=True)
        perpendicular = np.eye(3) - unit[:, :, None] * unit[:, None, :]
        self.sigma = np.sqrt(np.einsum("kij,kjl,kli->k", perpendicular, c, perpendicular) / 2.0)
        self.noise_covariance = block_diag(*c) if c.shape[0] else np.zeros((0, 0))

    def symbolic(self) -> SymbolicModel:
        """:func:`body_vectors_model` of the reference vectors; geodesic innovation."""
        return SymbolicModel(body_vectors_model, (self.reference,), innovation=geodesic_difference)

    def batch_key(self) -> Hashable:
        """The number of vectors: measurements with as many are predicted together."""
        return self.reference.shape[0]

    @classmethod
    def predict_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[tuple[Array, Array]]:
        return symbolic_predict_batch(measurements, attitudes)

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        k = self.reference.shape[0]
        if not jacobian:
            body = np.einsum("nij,kj->nki", attitude.as_matrix().reshape(-1, 3, 3), self.reference)
            return body.reshape(-1, 3 * k), None
        return super().predict(attitude)

    def innovation(self, predicted: Array) -> Array:
        """The geodesic difference of each measured vector from its prediction, compiled
        (:func:`attopt.formulations.geodesic.geodesic_rows`) unless kernels are
        interpreted (:func:`~attopt.formulations.kernels.compiled_loops`; then its numpy
        reference, :func:`~attopt.formulations.geodesic.geodesic_reference`)."""
        geodesic = geodesic_rows if compiled_loops() else geodesic_reference
        return geodesic(predicted.reshape(-1, predicted.shape[-1]), self.z).reshape(predicted.shape)


@lru_cache(maxsize=32)
def referenced_model(model: Callable[..., Any]) -> Callable[..., Any]:
    """``(A, F, *params) -> model(A F, *params)``: a model of ``A_bo`` as one of ``A_bi``."""

    def referenced(attitude: Any, frame_inverse: Any, *parameters: Any) -> Any:
        return model(attitude @ frame_inverse, *parameters)

    referenced.__name__ = f"referenced_{model.__name__}"
    return referenced


class ReferencedMeasurement(AttitudeMeasurement):
    """``inner`` (a model of ``A_bo``) as a model of ``A_bi = A_bo A_oi``.

    Filters carry the attitude relative to the frame the gyro's rates refer to
    (inertial); measurement models may be written relative to another frame
    (the orbit frame).  With ``frame = A_oi`` (inertial -> model reference),
    ``A_bo = A_bi A_oi^T``; a body-frame error is the same for both, so values
    and Jacobians are the inner model's at ``A_bi * frame.inv()``.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import ReferencedMeasurement, VectorMeasurement
        >>> orbit = Rotation.from_rotvec([0.0, 0.0, 0.3])  # A_oi: inertial -> orbit
        >>> in_orbit = VectorMeasurement([[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], 1e-3)  # of A_bo
        >>> inertial = ReferencedMeasurement(in_orbit, orbit)  # of A_bi = A_bo A_oi
        >>> bool(np.allclose(inertial.predict(orbit)[0], in_orbit.predict(Rotation.identity())[0]))
        True
    """

    def __init__(self, inner: AttitudeMeasurement, frame: Rotation) -> None:
        self.inner = inner
        self.frame_inverse = frame.inv()
        self.z = inner.z
        self.noise_covariance = inner.noise_covariance
        self.blocks = inner.blocks
        self.sources = inner.sources

    def symbolic(self) -> SymbolicModel:
        """The inner model at ``A F`` with ``F = A_oi^T`` as a leading parameter."""
        inner = self.inner.symbolic_model()
        return SymbolicModel(
            referenced_model(inner.model),
            (self.frame_inverse.as_matrix(), *inner.parameters),
            inner.rows,
            inner.innovation,
            inner.innovation_parameters,
        )

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        return self.inner.predict(attitude * self.frame_inverse, jacobian)

    def batch_key(self) -> Hashable | None:
        """The inner measurement's class and key (``None``: predicted alone)."""
        key = self.inner.batch_key()
        return None if key is None else (type(self.inner), key)

    @classmethod
    def predict_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[tuple[Array, Array]]:
        inner, composed = cls._inner_batch(measurements, attitudes)
        return type(inner[0]).predict_batch(inner, composed)

    @classmethod
    def noise_covariance_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[Array]:
        inner_type = type(measurements[0].inner)
        if not _noise_depends_on_attitude(inner_type):
            return [m.noise_covariance for m in measurements]  # no attitude to compose
        inner, composed = cls._inner_batch(measurements, attitudes)
        return inner_type.noise_covariance_batch(inner, composed)

    @classmethod
    def offset_slope_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[Array]:
        inner, composed = cls._inner_batch(measurements, attitudes)
        return type(inner[0]).offset_slope_batch(inner, composed)

    @staticmethod
    def _inner_batch(
        measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> tuple[list[AttitudeMeasurement], Rotation]:
        """The inner measurements and the attitudes of their model (``A F`` each)."""
        frames = Rotation.concatenate([m.frame_inverse for m in measurements])
        return [m.inner for m in measurements], attitudes * frames

    def innovation(self, predicted: Array) -> Array:
        return self.inner.innovation(predicted)

    def noise_covariance_at(self, attitude: Rotation) -> Array:
        if not _noise_depends_on_attitude(type(self.inner)):
            return self.noise_covariance
        return self.inner.noise_covariance_at(attitude * self.frame_inverse)

    def with_offsets(self, offsets: Array) -> ReferencedMeasurement:
        return ReferencedMeasurement(self.inner.with_offsets(offsets), self.frame_inverse.inv())

    def offset_slope(self, attitude: Rotation) -> Array:
        return self.inner.offset_slope(attitude * self.frame_inverse)

    def with_offset_spread(self, spread: float) -> ReferencedMeasurement:
        inner = self.inner.with_offset_spread(spread)
        return ReferencedMeasurement(inner, self.frame_inverse.inv())


def _noise_depends_on_attitude(cls: type[AttitudeMeasurement]) -> bool:
    """Whether the class overrides :meth:`AttitudeMeasurement.noise_covariance_at` (else its
    ``R`` is :attr:`~AttitudeMeasurement.noise_covariance` at every attitude)."""
    return cls.noise_covariance_at is not AttitudeMeasurement.noise_covariance_at
