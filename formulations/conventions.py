"""Frame and attitude conventions of attopt (see ``docs/conventions.md``).

* An attitude ``A`` maps components in a reference frame to components in the
  body frame, ``b = A r`` (Wahba's form, Cilden Guler et al. 2017 eq. 14).  It is carried as a
  :class:`scipy.spatial.transform.Rotation` whose ``as_matrix()`` is ``A``, so
  ``A.apply(r) == b``.
* The quaternion exchange format is scipy's: Hamilton, scalar last
  ``[x, y, z, w]``, of the rotation ``A``.  The Shuster quaternion of Cilden Guler et al. 2017
  eq. 21 (``A(q) = (q4^2 - |q|^2) I + 2 q q^T - 2 q4 [q x]``) is its conjugate,
  i.e. the scipy quaternion of ``A.inv()``.
* Euler angles are the 3-2-1 sequence (yaw psi, pitch theta, roll phi) of
  Liu et al. 2023 eq. 8: ``A = R1(phi) R2(theta) R3(psi)`` with ``Ri`` the frame
  (passive) rotation about axis ``i``.
* The attitude error is the rotation vector of ``A_est * A_true.inv()``; its
  components are along the body axes (x roll, y pitch, z yaw).
* The orbit frame (local vertical, local horizontal) has ``z_o`` towards nadir
  ``-r/|r|``, ``y_o`` along the negative orbit normal ``-(r x v)/|r x v|`` and
  ``x_o = y_o x z_o`` (along the velocity for a circular orbit).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

EULER_SEQUENCE = "ZYX"
"""scipy's intrinsic sequence whose inverse is Liu et al. 2023 eq. 8."""


def attitude_from_euler321(yaw: ArrayLike, pitch: ArrayLike, roll: ArrayLike) -> Rotation:
    """Attitude ``A = R1(roll) R2(pitch) R3(yaw)`` of Liu et al. 2023 eq. 8 (angles in rad).

    Example::

        >>> import numpy as np
        >>> from attopt import attitude_from_euler321, euler321_from_attitude
        >>> attitude = attitude_from_euler321(*np.radians([30.0, -10.0, 5.0]))
        >>> np.degrees(euler321_from_attitude(attitude)).round(6).tolist()
        [30.0, -10.0, 5.0]
    """
    angles = np.stack(np.broadcast_arrays(yaw, pitch, roll), axis=-1)
    return Rotation.from_euler(EULER_SEQUENCE, angles).inv()


def euler321_from_attitude(attitude: Rotation) -> NDArray[np.float64]:
    """Return ``[yaw, pitch, roll]`` (rad, last axis) of Liu et al. 2023 eq. 8.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import euler321_from_attitude
        >>> yawed = Rotation.from_rotvec([0.0, 0.0, -0.5])  # A = R3(0.5 rad)
        >>> np.degrees(euler321_from_attitude(yawed)).round(3).tolist()
        [28.648, 0.0, 0.0]
    """
    return attitude.inv().as_euler(EULER_SEQUENCE)


def shuster_quaternion(attitude: Rotation) -> NDArray[np.float64]:
    """Shuster quaternion ``[q1, q2, q3, q4]`` (scalar last) of Cilden Guler et al. 2017 eq. 21."""
    return attitude.inv().as_quat(canonical=True)


def attitude_from_shuster_quaternion(q: ArrayLike) -> Rotation:
    """Attitude whose matrix is ``A(q)`` of Cilden Guler et al. 2017 eq. 21 (``q`` scalar last)."""
    return Rotation.from_quat(q).inv()


def attitude_error(estimate: Rotation, truth: Rotation) -> NDArray[np.float64]:
    """Body-frame rotation vector (rad) of ``estimate * truth.inv()``.

    Components are along body x (roll), y (pitch) and z (yaw).

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import attitude_error
        >>> truth = Rotation.from_rotvec([0.1, 0.2, 0.3])
        >>> estimate = Rotation.from_rotvec([1e-3, 0.0, 0.0]) * truth  # 1 mrad about body x
        >>> (attitude_error(estimate, truth).round(6) + 0.0).tolist()
        [0.001, 0.0, 0.0]
    """
    return (estimate * truth.inv()).as_rotvec()


def orbit_frame_attitude(position: ArrayLike, velocity: ArrayLike) -> Rotation:
    """Attitude of the orbit frame relative to the inertial frame, ``o = A_oi i``.

    Rows of the matrix are the orbit axes expressed in the inertial frame:
    ``z_o = -r/|r|`` (nadir), ``y_o = -(r x v)/|r x v|``, ``x_o = y_o x z_o``.
    """
    r = np.asarray(position, dtype=float)
    v = np.asarray(velocity, dtype=float)
    z = -r / np.linalg.norm(r, axis=-1, keepdims=True)
    h = np.cross(r, v)
    y = -h / np.linalg.norm(h, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return Rotation.from_matrix(np.stack([x, y, z], axis=-2))
