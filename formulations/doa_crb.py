"""Stochastic Cramer-Rao bound of a single far-field source's DOA on an array.

For ``X = a(eta) s + N`` (Yang et al. 2014 eq. 8) with ``s ~ CN(0, P)``, white noise
``N ~ CN(0, sigma^2 I)``, ``L`` independent snapshots and
``eta = (theta, phi)``, the stochastic (unconditional) CRB of Stoica and
Nehorai (IEEE Trans. ASSP 38(10), 1990, eq. 2.13) is

``CRB^{-1} = (2 L / sigma^2) Re[(D^H Pi D) (P a^H R^{-1} a P)]``,

``D = da / d eta`` and ``Pi = I - a a^H / M``.  With one source
``P a^H R^{-1} a P = M P^2 / (sigma^2 + M P)``, and since ``a = exp(j psi)``
with the real phase ``psi(eta)`` of Yang et al. 2014 eq. 20,
``D^H Pi D = G^T (I - 1 1^T / M) G`` with ``G = d psi / d eta`` ``(M, 2)``:

``CRB = (1 + 1 / (M SNR)) / (2 L SNR) [G^T (I - 1 1^T / M) G]^{-1}``,

``SNR = P / sigma^2`` per element.  ``G`` is CasADi's derivative of the phase
function (:meth:`~attopt.formulations.doa_array.UniformCircularArray.steering_phase`
of :func:`~attopt.formulations.doa_array.doa_unit_vector`), so the bound holds for
any planar array.  For the UCA the columns of ``G`` are
``k r cos theta cos(phi - varphi_m)`` and ``-k r sin theta sin(phi - varphi_m)``,
giving ``CRB_theta = (1 + 1 / (M SNR)) / (L M SNR (k r cos theta)^2)`` and
``CRB_phi`` the same with ``sin theta``: ``phi`` is unobservable on the array
axis and ``theta`` at the horizon (there the bound is ``inf``).
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from attopt.formulations.doa_array import (
    YANG2014_UCA,
    Array,
    UniformCircularArray,
    doa_unit_vector,
)
from attopt.formulations.kernels import evaluate_mapped

_SINGULAR = 1e-12
"""Relative determinant below which the information matrix is singular."""


@lru_cache(maxsize=8)
def phase_jacobian_function(array: UniformCircularArray) -> ca.Function:
    """``(theta, phi) -> d psi / d(theta, phi)`` ``(M, 2)``, CasADi AD of eq. 20."""
    angles = ca.SX.sym("angles", 2)
    phase = array.steering_phase(doa_unit_vector(angles[0], angles[1])).T
    return ca.Function("phase_jacobian", [angles], [ca.jacobian(phase, angles)])


def doa_information_geometry(
    theta: ArrayLike, phi: ArrayLike, array: UniformCircularArray = YANG2014_UCA
) -> Array:
    """``G^T (I - 1 1^T / M) G`` ``(..., 2, 2)`` (rad^-2) at DOAs ``(theta, phi)``."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    angles = np.stack([theta.ravel(), phi.ravel()], axis=-1)
    if angles.shape[0] == 0:
        return np.empty((*theta.shape, 2, 2))
    (g,) = evaluate_mapped(phase_jacobian_function(array), angles)
    centred = g - g.mean(axis=1, keepdims=True)
    return (np.swapaxes(centred, 1, 2) @ centred).reshape(*theta.shape, 2, 2)


def stochastic_crb(
    theta: ArrayLike,
    phi: ArrayLike,
    snr: ArrayLike,
    n_snapshots: ArrayLike,
    array: UniformCircularArray = YANG2014_UCA,
) -> Array:
    """CRB ``(..., 2, 2)`` (rad^2) of ``(theta, phi)`` (module docstring).

    ``snr`` is the linear input SNR per element (``inf`` gives zero); a
    direction where the information matrix is singular (the array axis for
    ``phi``, the horizon for ``theta``, where it is diagonal) gets ``inf``
    for the unobservable angle.
    """
    geometry = doa_information_geometry(theta, phi, array)
    snr = np.asarray(snr, dtype=float)
    with np.errstate(divide="ignore"):
        scale = (1.0 + 1.0 / (array.n_elements * snr)) / (2.0 * np.asarray(n_snapshots) * snr)
    scale = np.broadcast_to(scale, geometry.shape[:-2])[..., None, None]
    determinant = np.linalg.det(geometry)
    trace = np.trace(geometry, axis1=-2, axis2=-1)
    regular = determinant > _SINGULAR * trace**2
    inverse = np.zeros_like(geometry)
    inverse[regular] = np.linalg.inv(geometry[regular])
    with np.errstate(divide="ignore"):
        diagonal = 1.0 / np.diagonal(geometry[~regular], axis1=-2, axis2=-1)
    inverse[~regular] = np.where(np.eye(2, dtype=bool), diagonal[..., None], 0.0)
    with np.errstate(invalid="ignore"):
        return np.where(scale == 0.0, 0.0, scale * inverse)
