"""How attopt's attitude and error conventions map onto GTSAM's ``Rot3`` (pinned by tests).

attopt (``docs/conventions.md``, ``docs/filters.md``): the attitude ``A``
maps reference (inertial) components to body components, ``b = A r``; the
error of an estimate is the body-frame rotation vector ``delta`` of
``A_true = exp(delta) A_est``; the gyro bias error is ``delta_beta = beta -
beta_hat``.

GTSAM: a ``Rot3`` ``R`` of the AHRS factor is ``nRb``, body -> navigation
(reference), so ``R = A^T``.  ``R.retract(xi) = R * Rot3.Expmap(xi)`` is a
right (body-frame) perturbation (verified for gtsam 4.3.0), hence::

    A(xi) = (R Exp(xi))^T = exp(-xi) A,      delta = -xi.

Consequences used throughout :mod:`attopt.solvers.smoother`:

* a measurement model ``h`` with the interface's body-frame Jacobian ``J =
  dh/d delta`` (:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement`)
  has ``dh/d xi = -J``;
* GTSAM's bias variable is a plain 3-vector whose retraction is addition, so
  its tangent ``d`` is ``delta_beta`` itself;
* a marginal covariance ``C`` of ``[xi, d]`` from ``gtsam.Marginals`` is the
  covariance of ``[delta, delta_beta] = T [xi, d]``, ``T = diag(-I, I)``: the
  attitude and bias blocks are unchanged, the cross block changes sign
  (:func:`error_state_covariance`).
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]

SIGN = np.diag([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
"""``T`` with ``[delta, delta_beta] = T [xi, d]``."""


def attitude_key(k: int) -> int:
    """GTSAM key of the attitude (``Rot3``) of node ``k``."""
    return gtsam.symbol("x", k)


def bias_key(k: int) -> int:
    """GTSAM key of the gyro bias (3-vector) of node ``k``."""
    return gtsam.symbol("b", k)


def offset_key(j: int) -> int:
    """GTSAM key of the ``j``-th transmitter offset (1-vector) of a pass."""
    return gtsam.symbol("o", j)


def rot3(attitude: Rotation) -> gtsam.Rot3:
    """``R = A^T`` (body -> reference) of one attitude ``A``."""
    return gtsam.Rot3(attitude.as_matrix().T)


def attitude(rotation: gtsam.Rot3) -> Rotation:
    """``A = R^T`` of one ``Rot3``."""
    return Rotation.from_matrix(rotation.matrix().T)


def retract(attitudes: Rotation, xi: Array) -> Rotation:
    """``exp(-xi) A``: the attitudes of ``R.retract(xi)`` for a stack ``(n, 3)`` of ``xi``."""
    return Rotation.from_rotvec(-np.asarray(xi, dtype=float)) * attitudes


def error_state_covariance(covariance: Array) -> Array:
    """Covariance ``(..., 6, 6)`` of ``[delta, delta_beta]`` from that of ``[xi, d]``."""
    return SIGN @ np.asarray(covariance, dtype=float) @ SIGN


def node_marginal(source: object, node: int, cross: bool) -> Array:
    """Marginal covariance ``(6, 6)`` of ``[xi, d]`` at ``node`` from a
    ``GaussianBayesTree`` or ``ISAM2`` (both answer the same queries): the joint
    ``6 x 6`` (``cross``) or the per-key blocks with zero cross blocks."""
    x, b = attitude_key(node), bias_key(node)
    out = np.zeros((6, 6))
    if cross:
        joint = source.jointMarginalCovariance([x, b])
        out[:3, :3], out[3:, 3:], out[:3, 3:] = joint.at(x, x), joint.at(b, b), joint.at(x, b)
        out[3:, :3] = out[:3, 3:].T
    else:
        out[:3, :3], out[3:, 3:] = source.marginalCovariance(x), source.marginalCovariance(b)
    return out


def to_values(attitudes: Rotation, bias: Array, offsets: Array | None = None) -> gtsam.Values:
    """``gtsam.Values`` with one ``Rot3`` and one bias vector per node, and the
    transmitter ``offsets`` (1-vectors) if given."""
    values = gtsam.Values()
    matrices = attitudes.as_matrix().reshape(-1, 3, 3)
    for k, (a, b) in enumerate(zip(matrices, np.asarray(bias, dtype=float), strict=True)):
        values.insert(attitude_key(k), gtsam.Rot3(a.T))
        values.insert(bias_key(k), np.array(b))
    for j, o in enumerate(() if offsets is None else offsets):
        values.insert(offset_key(j), np.array([o]))
    return values


def from_values(values: gtsam.Values, n: int) -> tuple[Rotation, Array]:
    """Attitudes and biases of nodes ``0 .. n - 1`` in ``values``."""
    matrices = np.stack([values.atRot3(attitude_key(k)).matrix().T for k in range(n)])
    bias = np.stack([values.atVector(bias_key(k)) for k in range(n)])
    return Rotation.from_matrix(matrices), bias


def step_arrays(step: gtsam.VectorValues, n: int) -> tuple[Array, Array]:
    """``xi`` ``(n, 3)`` and ``d`` ``(n, 3)`` of a ``VectorValues`` over the nodes."""
    xi = np.stack([step.at(attitude_key(k)) for k in range(n)])
    d = np.stack([step.at(bias_key(k)) for k in range(n)])
    return xi, d
