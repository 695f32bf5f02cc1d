"""Rigid-body dynamics of a satellite with momentum wheels (Yang et al. 2014 eqs. 23, 25).

Euler's equation with the wheels' angular momentum ``h`` (body axes, N m s),
torque free and with ``h_dot = 0``::

    I omega_dot = -omega x (I omega + h)

written once for numpy and CasADi (:func:`angular_acceleration`): the
``doa-ground`` scenario integrates it for the truth and Yang et al. 2014's
EKF (:mod:`attopt.solvers.doa.ekf`) steps it in its prediction.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from attopt.formulations.symbolic import CASADI, namespace_of

YANG2014_INERTIA = np.array(
    [[6.6199, 0.01636, 0.2363], [0.01636, 8.95, 0.2247], [0.2363, 0.2247, 9.4968]]
)
"""Inertia matrix of Yang et al. 2014 eq. 25 (kg m^2)."""


def angular_acceleration(omega: Any, wheel_momentum: Any, inertia: ArrayLike) -> Any:
    """``omega_dot = I^-1 (-omega x (I omega + h))`` (Yang et al. 2014 eq. 23, torque free,
    ``h_dot = 0``).

    numpy: ``(..., 3)`` rates and momenta; CasADi: ``3 x 1`` columns.
    """
    inertia = np.asarray(inertia, dtype=float)
    if namespace_of(omega, wheel_momentum) is CASADI:
        momentum = ca.DM(inertia) @ omega + wheel_momentum
        return ca.solve(ca.DM(inertia), -ca.cross(omega, momentum))
    omega = np.asarray(omega, dtype=float)
    momentum = omega @ inertia.T + wheel_momentum
    return np.linalg.solve(inertia, -np.cross(omega, momentum)[..., None])[..., 0]
