"""The maximum a posteriori loss of one snapshot, written symbolically for any mix of types.

Unknown: the attitude increment ``v`` of ``A = C(v) A_ref``
(:func:`attopt.formulations.attitude_model.increment_matrix`, Liu et al. 2023
eq. 28: ``v`` is the body-frame rotation-vector error to first order).
Loss:

    ``L(v) = sum_k 1/2 nu_k^T R_k^-1 nu_k  +  1/2 e^T P^-1 e``

with ``nu_k = innovation_k(z_k, h_k(C(v) A_ref))`` each measurement's own
innovation of its own symbolic model
(:meth:`~attopt.formulations.attitude_measurement.AttitudeMeasurement.symbolic`:
geodesic for unit vectors, wrapped angles for Euler angles and DOA azimuths)
and, with a prior ``(A_p, P)``, ``e`` the error of ``A`` relative to ``A_p``,
``A = exp(e) A_p``, taken as four times the modified Rodrigues parameters of
``C(v) A_ref A_p^T`` (equal to ``v`` when ``A_ref = A_p``; the rotation vector
to second order).  The quaternion of ``C(v)`` is ``[2 p, 1 - |p|^2] / (1 +
|p|^2)``, ``p = v / 4``, composed with that of ``A_ref A_p^T`` by the
Hamilton product.

:func:`map_loss` builds ``L`` once per structure (measurement types, sizes and
noise layout, :attr:`MapTerm.structure`) with every value a parameter, in the
order of :func:`parameter_vector`: ``A_ref`` (9, column-major), then per
measurement its model parameters, ``z``, ``R^-1`` (the diagonal for
independent rows, else the matrix) and its innovation parameters, then with a
prior the quaternion of ``A_ref A_p^T`` (4, scalar last) and ``P^-1`` (9).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.attitude_model import increment_matrix
from attopt.formulations.measurement_model import SymbolicModel

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class MapTerm:
    """One measurement's term of the loss: its symbolic model, ``z`` and ``R^-1``."""

    model: SymbolicModel
    z: Array
    weight: Array
    """``R^-1``: ``(m,)`` for independent rows, else ``(m, m)``."""

    @classmethod
    def of(cls, measurement: AttitudeMeasurement, attitude: Rotation) -> MapTerm:
        """The term of ``measurement`` with its noise covariance at ``attitude``."""
        noise = np.asarray(measurement.noise_covariance_at(attitude), dtype=float)
        weight = 1.0 / noise if noise.ndim == 1 else np.linalg.inv(noise)
        return cls(measurement.symbolic_model(), np.asarray(measurement.z, float), weight)

    @property
    def structure(self) -> tuple[Any, ...]:
        """What the compiled loss depends on: the model's structure, ``m`` and the noise layout."""
        return (*self.model.structure, self.z.size, self.weight.ndim)

    def values(self) -> list[Array]:
        """This term's parameter values, in the order of :func:`map_loss`."""
        return [
            *(p.ravel(order="F") for p in self.model.parameters),
            self.z,
            self.weight.ravel(order="F"),
            *(p.ravel(order="F") for p in self.model.innovation_parameters),
        ]


def _term_loss(structure: tuple[Any, ...], attitude: Any) -> tuple[list[ca.SX], Any]:
    model, shapes, rows, innovation, innovation_shapes, m, weight_ndim = structure
    parameters = [ca.SX.sym(f"p{i}", *shape) for i, shape in enumerate(shapes)]
    z = ca.SX.sym("z", m)
    weight = ca.SX.sym("weight", m) if weight_ndim == 1 else ca.SX.sym("weight", m, m)
    extra = [ca.SX.sym(f"q{i}", *shape) for i, shape in enumerate(innovation_shapes)]
    h = model(attitude, *parameters)
    if rows is not None:
        h = h[list(rows)]
    nu = innovation(z, h, *extra)
    loss = 0.5 * ca.dot(nu, weight * nu) if weight_ndim == 1 else 0.5 * ca.bilin(weight, nu, nu)
    return [*parameters, z, weight, *extra], loss


def prior_error(v: Any, reference_to_prior: Any) -> Any:
    """``e = 4 mrp(C(v) D)`` with ``D = A_ref A_p^T`` given as its quaternion (module docstring)."""
    p = v / 4.0
    norm2 = ca.dot(p, p)
    q1 = ca.vertcat(2.0 * p, 1.0 - norm2) / (1.0 + norm2)
    v1, w1 = q1[:3], q1[3]
    v2, w2 = reference_to_prior[:3], reference_to_prior[3]
    vector = w1 * v2 + w2 * v1 + ca.cross(v1, v2)
    scalar = w1 * w2 - ca.dot(v1, v2)
    return 4.0 * vector / (1.0 + scalar)


def map_loss(structure: Sequence[tuple[Any, ...]], with_prior: bool) -> tuple[ca.SX, ca.SX, ca.SX]:
    """``(v, p, L)``: the increment, the parameter vector and the loss (module docstring)."""
    v = ca.SX.sym("v", 3)
    attitude_ref = ca.SX.sym("attitude_ref", 3, 3)
    attitude = increment_matrix(v) @ attitude_ref
    parameters = [attitude_ref]
    loss = ca.SX(0.0)
    for term in structure:
        symbols, term_loss = _term_loss(term, attitude)
        parameters += symbols
        loss += term_loss
    if with_prior:
        reference_to_prior = ca.SX.sym("reference_to_prior", 4)
        information = ca.SX.sym("prior_information", 3, 3)
        error = prior_error(v, reference_to_prior)
        parameters += [reference_to_prior, information]
        loss += 0.5 * ca.bilin(information, error, error)
    return v, ca.vertcat(*(ca.vec(symbol) for symbol in parameters)), loss


def parameter_vector(
    attitude_ref: Rotation,
    terms: Sequence[MapTerm],
    prior: tuple[Rotation, Array] | None = None,
) -> Array:
    """The values of :func:`map_loss`'s parameters; ``prior`` is ``(A_p, P^-1)``."""
    parts = [attitude_ref.as_matrix().ravel(order="F")]
    for term in terms:
        parts += term.values()
    if prior is not None:
        attitude, information = prior
        parts += [(attitude_ref * attitude.inv()).as_quat(), information.ravel(order="F")]
    return np.concatenate(parts)
