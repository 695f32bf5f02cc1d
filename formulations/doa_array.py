"""The smart-antenna array of Yang et al. 2014: geometry, steering vector and snapshots.

Array frame ``F_r`` (Yang et al. 2014 sec. 2, Fig. 1): the elements lie in its x-y
plane, which is parallel to the body x-y plane; ``z`` is the array axis.  A
direction of arrival (DOA) is ``(theta, phi)``: ``theta`` the polar angle of
the source direction from ``+z`` (``0 <= theta <= pi / 2`` on the side the
array faces), ``phi`` its azimuth from ``+x`` towards ``+y``, and the unit
vector towards the source is eq. 1 / eq. 12,
``S = [sin theta cos phi, sin theta sin phi, cos theta]``.

The uniform circular array (UCA) of sec. 4.1 has ``M = 12`` elements at
radius ``r = 150 mm``, element ``m`` at azimuth ``varphi_m = 2 pi (m - 1) / M``
(eq. 19); for wavelength ``lambda = 150 mm`` the element's phase lead is
``k r sin theta cos(phi - varphi_m)`` (eq. 20, ``k = 2 pi / lambda``) and the
steering vector ``a_m = exp(j k r sin theta cos(phi - varphi_m))`` (eq. 21).
The phase depends on ``S`` only through its components in the array plane,
so a planar array cannot tell ``theta`` from ``pi - theta`` (a source behind
the plane) and, at the horizon ``theta = pi / 2``, a change of ``theta``
changes no phase to first order.

Snapshots ``X(t) = a s(t) + N(t)`` (eq. 8) have complex circular Gaussian
signal and noise, unit noise power per element and signal power equal to the
input SNR per element.  Their sample covariance (eq. 10) can also be drawn
directly, at a cost independent of the number of snapshots (complex Wishart).

Functions take numpy arrays (vectorised over leading axes) and, where stated,
CasADi values (one direction, for automatic differentiation).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.kernels import evaluate_mapped
from attopt.formulations.symbolic import CASADI, namespace_of

Array = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


@dataclass(frozen=True)
class UniformCircularArray:
    """A uniform circular array in the x-y plane of its frame (Yang et al. 2014 eqs. 19-21)."""

    n_elements: int = 12
    radius_m: float = 0.15
    wavelength_m: float = 0.15

    @property
    def element_angles(self) -> Array:
        """``varphi_m = 2 pi (m - 1) / M`` (rad), ``m = 1..M`` (Yang et al. 2014 sec. 4.1)."""
        return 2.0 * np.pi * np.arange(self.n_elements) / self.n_elements

    @property
    def element_directions(self) -> Array:
        """``(M, 3)`` unit vectors ``M_r = [cos varphi_m, sin varphi_m, 0]`` (eq. 19)."""
        angles = self.element_angles
        return np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])

    @property
    def wavenumber_radius(self) -> float:
        """``k r = 2 pi r / lambda`` (rad): the phase scale of eq. 21."""
        return 2.0 * np.pi * self.radius_m / self.wavelength_m

    @property
    def first_null_radius(self) -> float:
        """First null of the beam, ``2.405 / (k r)``, in direction cosines of the array plane.

        The beam pattern ``|a(p0)^H a(p)| / M`` is ``|J0(k r |p - p0|)|`` (up
        to Bessel terms of order ``M``), whose first zero is 2.405.
        """
        return 2.404825557695773 / self.wavenumber_radius

    def steering_phase(self, direction: Any) -> Any:
        """Phase leads ``k r (S . M_r)`` of the elements for source direction ``S`` (eq. 20).

        numpy: ``direction`` ``(..., 3)`` -> ``(..., M)``; CasADi: a ``1 x 3``
        row -> ``1 x M``.  ``S`` need not be a unit vector (only its
        components in the array plane enter).
        """
        scaled = self.wavenumber_radius * self.element_directions.T
        if namespace_of(direction) is CASADI:
            return direction @ ca.DM(scaled)
        return np.asarray(direction, dtype=float) @ scaled


YANG2014_UCA = UniformCircularArray()
"""The 12-element UCA of Yang et al. 2014 sec. 4.1 (r = lambda = 150 mm)."""


def doa_unit_vector(theta: Any, phi: Any) -> Any:
    """``S = [sin theta cos phi, sin theta sin phi, cos theta]`` (Yang et al. 2014 eqs. 1, 12).

    numpy: ``(...)`` angles -> ``(..., 3)``; CasADi: scalars -> ``1 x 3`` row.
    """
    symbolic = namespace_of(theta, phi) is CASADI
    sin, cos = (ca.sin, ca.cos) if symbolic else (np.sin, np.cos)
    entries = (sin(theta) * cos(phi), sin(theta) * sin(phi), cos(theta))
    if symbolic:
        return ca.horzcat(*entries)
    return np.stack(np.broadcast_arrays(*entries), axis=-1)


def doa_from_unit_vector(direction: Any) -> tuple[Any, Any]:
    """``(theta, phi)`` of a direction (inverse of eq. 12; any length, numpy or CasADi rows).

    ``theta = atan2(sqrt(x^2 + y^2), z)`` in ``[0, pi]``, ``phi = atan2(y, x)``
    in ``(-pi, pi]`` (``0`` on the array axis, where it is undefined).
    """
    xp = namespace_of(direction)
    x, y, z = xp.components(direction)
    return xp.atan2(xp.sqrt(x**2 + y**2), z), xp.atan2(y, x)


@lru_cache(maxsize=1)
def _unit_vector_jacobian_function() -> ca.Function:
    angles = ca.SX.sym("angles", 2)
    direction = doa_unit_vector(angles[0], angles[1]).T
    return ca.Function("doa_jacobian", [angles], [ca.jacobian(direction, angles)])


def doa_jacobian(theta: ArrayLike, phi: ArrayLike) -> Array:
    """``dS / d(theta, phi)`` ``(..., 3, 2)`` of eq. 12, by CasADi AD."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    angles = np.stack([theta.ravel(), phi.ravel()], axis=-1)
    if angles.shape[0] == 0:
        return np.empty((*theta.shape, 3, 2))
    (jacobian,) = evaluate_mapped(_unit_vector_jacobian_function(), angles)
    return jacobian.reshape(*theta.shape, 3, 2)


def unit_vector_covariance(theta: ArrayLike, phi: ArrayLike, covariance: ArrayLike) -> Array:
    """Covariance ``J Sigma J^T`` ``(..., 3, 3)`` of ``S`` (eq. 12) from that of ``(theta, phi)``.

    First order; of rank 2 (no error along ``S``).  This is the ``R_W`` of
    the error ``W`` of eq. 12 for one measured direction (eq. 22 takes its
    diagonal from simulations).
    """
    jacobian = doa_jacobian(theta, phi)
    return jacobian @ np.asarray(covariance, dtype=float) @ np.swapaxes(jacobian, -1, -2)


def steering_vector(
    theta: ArrayLike, phi: ArrayLike, array: UniformCircularArray = YANG2014_UCA
) -> ComplexArray:
    """``a(theta, phi)`` ``(..., M)`` of Yang et al. 2014 eq. 21."""
    direction = doa_unit_vector(np.asarray(theta, float), np.asarray(phi, float))
    return np.exp(1j * array.steering_phase(direction))


def simulate_snapshots(
    theta: ArrayLike,
    phi: ArrayLike,
    snr_db: float,
    n_snapshots: int,
    rng: np.random.Generator,
    array: UniformCircularArray = YANG2014_UCA,
) -> ComplexArray:
    """``X = a(theta, phi) s + N`` ``(..., M, L)`` (Yang et al. 2014 eqs. 8-10).

    ``s`` and every element of ``N`` are independent circular complex
    Gaussian, ``E|n|^2 = 1`` and ``E|s|^2 = 10^(snr_db / 10)`` (the input
    SNR per element); one snapshot set per direction in ``theta``, ``phi``.
    """
    if int(n_snapshots) != n_snapshots or n_snapshots < 0:
        raise InvalidObservationError(f"number of snapshots must be >= 0, got {n_snapshots}")
    a = steering_vector(theta, phi, array)
    shape = a.shape[:-1]
    power = 10.0 ** (snr_db / 10.0)
    signal = _circular_gaussian(rng, (*shape, 1, n_snapshots)) * np.sqrt(power)
    snapshots = _circular_gaussian(rng, (*shape, array.n_elements, n_snapshots))
    snapshots += a[..., :, None] * signal
    return snapshots


def simulate_sample_covariance(
    theta: ArrayLike,
    phi: ArrayLike,
    snr_db: float,
    n_snapshots: int,
    rng: np.random.Generator,
    array: UniformCircularArray = YANG2014_UCA,
) -> ComplexArray:
    """Sample covariance ``R_hat = X X^H / L`` ``(..., M, M)`` (eq. 10) of the snapshots
    of :func:`simulate_snapshots`, drawn directly at a cost independent of ``L``.

    The columns of ``X`` (eq. 8) are independent ``CN(0, R)`` with
    ``R = P a a^H + I`` (eq. 9, ``P = 10^(snr_db / 10)``), so ``X = R^(1/2) Z``
    with ``Z`` ``M x L`` standard circular Gaussian and ``L R_hat`` is complex
    Wishart.  Bartlett: ``Z Z^H = T T^H`` with ``T`` ``M x K``,
    ``K = min(M, L)``, lower triangular (trapezoidal for ``L < M``, where
    ``R_hat`` has rank ``L``), ``|T_kk|^2 ~ Gamma(L - k)`` (chi-square with
    ``2 (L - k)`` degrees of freedom over 2, ``k = 0..K-1``) and ``CN(0, 1)``
    below the diagonal, all independent.  With ``|a|^2 = M`` (``R`` has the
    eigenvalue ``1 + P M`` along ``a`` and 1 across it),
    ``R^(1/2) = I + c a a^H``, ``c = (sqrt(1 + P M) - 1) / M``.  The
    distribution is that of the snapshots' ``R_hat``; the draws are not
    (``rng`` is consumed differently).
    """
    if int(n_snapshots) != n_snapshots or n_snapshots < 1:
        raise InvalidObservationError(f"number of snapshots must be >= 1, got {n_snapshots}")
    a = steering_vector(theta, phi, array)
    shape, m = a.shape[:-1], array.n_elements
    k = min(m, int(n_snapshots))
    rows, columns = np.tril_indices(m, -1, k)
    factor = np.zeros((*shape, m, k), dtype=complex)
    factor[..., rows, columns] = _circular_gaussian(rng, (*shape, rows.size))
    diagonal = np.arange(k)
    factor[..., diagonal, diagonal] = np.sqrt(
        rng.standard_gamma(n_snapshots - diagonal, (*shape, k))
    )
    c = (np.sqrt(1.0 + 10.0 ** (snr_db / 10.0) * m) - 1.0) / m
    factor += (c * a)[..., :, None] * (np.conj(a)[..., None, :] @ factor)
    return factor @ np.conj(np.swapaxes(factor, -1, -2)) / n_snapshots


def _circular_gaussian(rng: np.random.Generator, shape: tuple[int, ...]) -> ComplexArray:
    """Unit-power circular complex Gaussian samples (real and imaginary parts interleaved)."""
    draws = rng.standard_normal((*shape, 2))
    draws *= np.sqrt(0.5)
    return draws.view(complex)[..., 0]
