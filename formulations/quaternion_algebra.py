"""Unit-quaternion algebra on numpy arrays, for the filters' per-epoch loops.

Quaternions are scipy's exchange format (``docs/conventions.md``): scalar last,
``[x, y, z, w]``, the Hamilton product, so that :func:`compose` of ``p`` and
``q`` is the quaternion of ``Rotation.from_quat(p) * Rotation.from_quat(q)``.

Written by hand for speed, not for want of a library: a recursive filter
composes, perturbs and differences a handful of attitudes per epoch, and each
call of ``scipy.spatial.transform.Rotation`` costs 20-110 us there (its array-API
implementation, scipy 1.17), against a few microseconds for these formulas on
arrays of one to a few dozen quaternions.  Each function equals its scipy
counterpart to round-off (``tests/test_quaternion_algebra.py``); results leave
the filters as ``Rotation`` objects again.  No canonical sign is imposed: like
scipy's product, :func:`compose` returns whichever sign the formula gives.

Example::

    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> from attopt.formulations.quaternion_algebra import compose, from_rotation_vector
    >>> p, q = from_rotation_vector([0.1, 0.0, 0.0]), from_rotation_vector([0.0, 0.2, 0.0])
    >>> expected = (Rotation.from_rotvec([0.1, 0, 0]) * Rotation.from_rotvec([0, 0.2, 0])).as_quat()
    >>> bool(np.allclose(compose(p, q), expected, atol=1e-15))
    True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


_LEFT_INDEX = np.array([3, 2, 1, 0, 2, 3, 0, 1, 1, 0, 3, 2, 0, 1, 2, 3])
_LEFT_SIGN = np.array([1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1, 1, -1, -1, -1, 1], dtype=float)
_CONJUGATE = np.array([-1.0, -1.0, -1.0, 1.0])


def left_matrices(q: ArrayLike) -> Array:
    """``(..., 4, 4)`` matrices ``L(q)`` with ``L(q) r = compose(q, r)`` (Hamilton product,
    scalar last), so that a chain of products is a chain of matrix products: rows
    ``[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]``."""
    q = np.asarray(q, dtype=float)
    return (q[..., _LEFT_INDEX] * _LEFT_SIGN).reshape(*q.shape[:-1], 4, 4)


def compose(p: ArrayLike, q: ArrayLike) -> Array:
    """The quaternion of ``Rotation.from_quat(p) * Rotation.from_quat(q)`` (``(..., 4)``,
    broadcast): ``[p_w q_v + q_w p_v + p_v x q_v, p_w q_w - p_v . q_v]``."""
    return (left_matrices(p) @ np.asarray(q, dtype=float)[..., None])[..., 0]


def conjugate(q: ArrayLike) -> Array:
    """The quaternion of the inverse rotation: ``[-q_v, q_w]``."""
    return np.asarray(q, dtype=float) * _CONJUGATE


def from_rotation_vector(v: ArrayLike) -> Array:
    """The quaternion ``[sin(theta / 2) v / theta, cos(theta / 2)]`` of the rotation by
    ``theta = |v|`` about ``v`` (``Rotation.from_rotvec(v).as_quat()``), ``(..., 4)``;
    ``sin(theta / 2) / theta`` is ``numpy.sinc``'s, exact at and near 0."""
    v = np.asarray(v, dtype=float)
    angle = np.sqrt((v * v).sum(axis=-1, keepdims=True))
    return np.concatenate([0.5 * np.sinc(angle / (2.0 * np.pi)) * v, np.cos(0.5 * angle)], axis=-1)


def from_mrp(p: ArrayLike) -> Array:
    """The quaternion ``[2 p, 1 - |p|^2] / (1 + |p|^2)`` of the modified Rodrigues
    parameters ``p`` (``Rotation.from_mrp(p).as_quat()``), ``(..., 4)``."""
    p = np.asarray(p, dtype=float)
    norm2 = (p * p).sum(axis=-1, keepdims=True)
    return np.concatenate([2.0 * p, 1.0 - norm2], axis=-1) / (1.0 + norm2)


def to_mrp(q: ArrayLike) -> Array:
    """The modified Rodrigues parameters ``q_v / (1 + q_w)`` of the unit quaternion ``q``,
    taken with ``q_w >= 0`` (rotation angle at most 180 deg, as ``Rotation.as_mrp``),
    ``(..., 3)``."""
    q = np.asarray(q, dtype=float)
    sign = np.copysign(1.0, q[..., 3:])
    return sign * q[..., :3] / (1.0 + sign * q[..., 3:])
