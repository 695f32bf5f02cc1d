"""MUSIC direction-of-arrival estimation with continuous peak refinement (Yang et al. 2014 eq. 11).

For each snapshot set ``X`` (``M x L``):

1. Sample covariance ``R = X X^H / L`` (eq. 10) and its eigen-decomposition.
   With one source the noise subspace ``V_M`` is the orthogonal complement of
   the principal eigenvector ``e``, so ``V_M V_M^H = I - e e^H`` and the MUSIC
   spectrum (eq. 11) is ``P = 1 / (M (1 - s))``,
   ``s(p) = |e^H a(p)|^2 / M`` in ``[0, 1]``.  ``a`` depends on the direction
   only through ``p = (sin theta cos phi, sin theta sin phi)``, the direction
   cosines in the array plane, so the search runs over ``p`` (no singularity
   at the array axis).  :meth:`MusicEstimator.estimate_covariance` starts
   here from given ``R`` and ``L`` (e.g. drawn by
   :func:`attopt.formulations.doa_array.simulate_sample_covariance`).
2. Coarse grid: a square lattice of ``p`` over the visible cone
   ``theta <= cone_half_angle``; the grid maximum and the highest other local
   maximum (at least its 8 lattice neighbours) outside the main lobe
   (first-null radius) are both refined.
3. Refinement: damped Newton ascent on ``s(p)`` with gradient and Hessian by
   CasADi AD, vectorised over all sets, to a step below ``1e-8``, so no grid
   quantisation remains.  Yang et al. 2014's own DOA errors level off at 0.287 and
   0.289 deg (its Tables 1-2), which is ``1 deg / sqrt(12)``: the
   quantisation of a 1-degree search grid.
4. Covariance: the stochastic CRB (:func:`attopt.formulations.doa_crb.stochastic_crb`)
   at the estimate, with the SNR given or estimated from the eigenvalues
   (MUSIC is asymptotically efficient for one source, so this is its
   large-``L`` covariance), widened below the threshold output SNR (below).

Threshold region.  Below an output SNR ``L M SNR`` (the matched beamformer's) of
about 150 the estimates are not yet asymptotic: the signal eigenvalue is not
well separated from the noise eigenvalues, and now and then the principal
eigenvector follows the noise to a sidelobe or the flank of the main lobe (a
subspace swap).  The CRB above roughly describes the typical error there, but not
its tail: measured on Yang et al. 2014's array (``docs/doa.md``, MUSIC's threshold
region), the share of estimates beyond the chi-square(2) ``1 - 1e-4`` quantile of
the CRB is 0.0013-0.004 at output SNRs of 12-120 and 0.0001-0.0007 from 190 up.
Their core is wider than the CRB too (variance 1.1-1.2 times it at output SNRs
of 76-120), and ``theta`` is biased by up to 0.05-0.18 of its sigma, depending on
the direction: a single estimate hardly shows it, but a filter or smoother that
averages hundreds of them does (measured on ``doa-ground``'s pass, ``docs/doa.md``:
a gyro-aided MEKF and Yang et al. 2014's RTS pass beyond the 1 - 1e-4 quantile
11-27 times as often as a consistent estimator).  So below the threshold the
covariance is the CRB times :attr:`MusicEstimator.threshold_variance_factor` (2),
the widening measured to make those filters consistent there, and
``diagnostics["below_threshold"]`` marks such estimates for the estimators that
must not trust their covariance's tail at all, such as a single-frame solution
(:attr:`MusicEstimator.threshold_output_snr`).

Outcomes (``reason`` of an invalid set; ``theta``, ``phi`` and the covariance
are NaN there):

* non-finite snapshots or covariance (``InvalidObservationError``);
* no signal eigenvalue above the noise floor (``UnobservableError``);
* ``L = 1`` without a given SNR: the noise power is not estimable from one
  snapshot, so neither is the covariance (``UnobservableError``);
* ambiguous peak: the MUSIC spectrum of the second peak is at least
  ``peak_ratio_threshold`` times the main one's (``UnobservableError``);
* source at the horizon, ``theta >= horizon_angle``: the planar array's phases
  do not change with ``theta`` there (``UnobservableError``);
* refinement not converged (``ConvergenceError``).

``L < M`` (rank-deficient ``R``) is not an error: ``I - e e^H`` is still the
noise projector of the rank-one signal model and, at ``L = 1``, MUSIC is the
matched beamformer of the single snapshot (the maximum-likelihood estimate).
Such sets are flagged in ``diagnostics["rank_deficient"]``; the noise power is
then estimated with ``(M - 1)(L - 1)`` degrees of freedom (below).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property, lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.doa_array import (
    YANG2014_UCA,
    Array,
    ComplexArray,
    UniformCircularArray,
    doa_from_unit_vector,
)
from attopt.formulations.doa_crb import stochastic_crb
from attopt.formulations.errors import (
    ConvergenceError,
    InvalidObservationError,
    UnobservableError,
)
from attopt.formulations.kernels import evaluate_mapped

SPECTRUM_BLOCK = 1024
"""Sets per block of the grid spectrum: about 30 MB of ``e^H a``, in few large BLAS calls."""

SECOND_PEAK_TOLERANCE = 1e-4
"""Refinement tolerance of the second peak, needed only for its value (error ~ 1e-8)."""


@dataclass(frozen=True)
class DoaEstimates:
    """DOA estimates of ``N`` snapshot sets with a per-set validity mask.

    Attributes:
        theta, phi: ``(N,)`` rad; ``phi`` in ``[0, 2 pi)``; NaN where invalid.
        covariance: ``(N, 2, 2)`` rad^2 of ``(theta, phi)``; NaN where invalid.
        valid: ``(N,)`` bool.
        reason: ``(N,)`` str, empty where valid.
        error: ``(N,)`` exception class of invalid sets, None where valid.
        diagnostics: ``peak_ratio`` (second / main MUSIC peak), ``snr`` (linear,
            per element, used for the covariance), ``output_snr`` (``L M snr``),
            ``below_threshold`` (``output_snr`` below the estimator's
            ``threshold_output_snr``: module docstring, Threshold region),
            ``rank_deficient`` (``L < M``), ``iterations`` (Newton steps of the main
            peak), each ``(N,)``.
    """

    theta: Array
    phi: Array
    covariance: Array
    valid: NDArray[np.bool_]
    reason: NDArray[np.object_]
    error: NDArray[np.object_]
    diagnostics: Mapping[str, Array]

    def raise_if_invalid(self, i: int) -> None:
        """Raise the exception recorded for set ``i`` (nothing if it is valid)."""
        if not self.valid[i]:
            raise self.error[i](f"MUSIC: {self.reason[i]}")


@lru_cache(maxsize=8)
def spectrum_function(array: UniformCircularArray) -> ca.Function:
    """``(p, Re e, Im e) -> (s, ds/dp, d2s/dp2)`` of ``s = |e^H a(p)|^2 / M``, CasADi AD."""
    m = array.n_elements
    p = ca.SX.sym("p", 2)
    real, imag = ca.SX.sym("real", m), ca.SX.sym("imag", m)
    phase = array.steering_phase(ca.horzcat(p[0], p[1], 0.0)).T
    cos, sin = ca.cos(phase), ca.sin(phase)
    response_re = ca.dot(real, cos) + ca.dot(imag, sin)
    response_im = ca.dot(real, sin) - ca.dot(imag, cos)
    s = (response_re**2 + response_im**2) / m
    hessian, gradient = ca.hessian(s, p)
    return ca.Function("music_spectrum", [p, real, imag], [s, gradient, hessian])


@dataclass(frozen=True)
class _Lattice:
    """The coarse grid: a square lattice of direction cosines in the visible cone.

    Attributes:
        grid: ``(G, 2)`` direction cosines of the lattice points in the cone.
        neighbours: ``(G, 8)`` grid indices of each point's 8 lattice
            neighbours; the point's own index where a neighbour is outside
            the cone (a point compared with itself is not lower).
        outside: ``(G, G)`` whether two grid points are farther apart than the
            main lobe's first-null radius.
    """

    grid: Array
    neighbours: NDArray[np.intp]
    outside: NDArray[np.bool_]


@dataclass(frozen=True)
class MusicEstimator:
    """MUSIC on ``array`` (module docstring); call :meth:`estimate`.

    Attributes:
        array: the array (default: Yang et al. 2014's UCA).
        cone_half_angle: polar angle of the grid's visible cone (rad); the
            default covers Yang et al. 2014's ``theta <= 62 deg`` with a margin.
        grid_step: lattice spacing in direction cosines (the main lobe's
            first-null radius is 0.38 for the paper's UCA).
        peak_ratio_threshold: ambiguous when the second peak's MUSIC
            spectrum is at least this fraction of the main peak's.
        horizon_angle: estimates with ``theta`` at or beyond it are rejected.
        threshold_output_snr: output SNR ``L M snr`` below which an estimate is
            marked ``below_threshold`` (module docstring, Threshold region; measured
            for Yang et al. 2014's 12-element array).
        threshold_variance_factor: below ``threshold_output_snr`` the covariance is
            the CRB times this factor (module docstring, Threshold region; 1 gives
            the CRB everywhere).
        step_tolerance: Newton step (direction cosines) that ends refinement
            (the error after it is of the order of its square).
        max_iterations: Newton iterations before ``ConvergenceError``.
    """

    array: UniformCircularArray = YANG2014_UCA
    cone_half_angle: float = float(np.radians(70.0))
    grid_step: float = 0.04
    peak_ratio_threshold: float = 0.5
    horizon_angle: float = float(np.radians(85.0))
    threshold_output_snr: float = 150.0
    threshold_variance_factor: float = 2.0
    step_tolerance: float = 1e-8
    max_iterations: int = 40

    @cached_property
    def grid(self) -> Array:
        """``(G, 2)`` direction cosines of the coarse grid (square lattice in the cone)."""
        return self._lattice.grid

    @cached_property
    def _lattice(self) -> _Lattice:
        """The grid, its lattice neighbours and the outside-main-lobe table."""
        radius = np.sin(self.cone_half_angle)
        n = int(np.ceil(radius / self.grid_step))
        i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1), indexing="ij")
        points = self.grid_step * np.column_stack([i.ravel(), j.ravel()])
        inside = np.hypot(points[:, 0], points[:, 1]) <= radius
        index = np.full(i.size, -1)
        index[inside] = np.arange(inside.sum())
        index = np.pad(index.reshape(i.shape), 1, constant_values=-1)
        offsets = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)]
        ii, jj = i.ravel()[inside] + n + 1, j.ravel()[inside] + n + 1
        neighbours = np.column_stack([index[ii + a, jj + b] for a, b in offsets])
        own = np.arange(len(ii))[:, None]
        grid = points[inside]
        distance = np.linalg.norm(grid[:, None, :] - grid[None, :, :], axis=-1)
        return _Lattice(
            grid,
            np.where(neighbours >= 0, neighbours, own),
            distance > self.array.first_null_radius,
        )

    @cached_property
    def _grid_steering(self) -> ComplexArray:
        """``(M, G)`` steering vectors of the grid."""
        direction = np.column_stack([self.grid, np.zeros(len(self.grid))])
        return np.exp(1j * self.array.steering_phase(direction)).T

    def estimate(self, snapshots: ArrayLike, snr_db: ArrayLike | None = None) -> DoaEstimates:
        """DOAs of snapshot sets ``(..., M, L)`` (sets flattened to ``N``).

        ``snr_db``: known input SNR per element (scalar or ``(N,)``) for the
        covariance; by default it is estimated from the eigenvalues of ``R``.
        Raises :class:`InvalidObservationError` for a wrong number of
        elements, no snapshots (``L = 0``) or non-complex-convertible input.
        """
        x = _complex_sets(snapshots, "snapshots", self.array.n_elements, None)
        n_snapshots = x.shape[-1]
        x, finite = _zero_non_finite(x)
        covariance = x @ np.conj(np.swapaxes(x, 1, 2)) / n_snapshots
        return self._estimate(covariance, n_snapshots, snr_db, ~finite, "non-finite snapshots")

    def estimate_covariance(
        self, covariance: ArrayLike, n_snapshots: int, snr_db: ArrayLike | None = None
    ) -> DoaEstimates:
        """DOAs from sample covariances ``R = X X^H / L`` (eq. 10) ``(..., M, M)`` of ``L``
        snapshots each, as :meth:`estimate` of the snapshots would give them.

        Only the lower triangle of ``R`` is read.  ``n_snapshots`` (``L >= 1``)
        sets the noise degrees of freedom, the ``L < M`` flag and the CRB.
        Raises :class:`InvalidObservationError` for a wrong shape or ``L``.
        """
        if int(n_snapshots) != n_snapshots or n_snapshots < 1:
            raise InvalidObservationError(f"number of snapshots must be >= 1, got {n_snapshots}")
        m = self.array.n_elements
        r = _complex_sets(covariance, "covariance", m, m)
        r, finite = _zero_non_finite(r)
        return self._estimate(r, int(n_snapshots), snr_db, ~finite, "non-finite covariance")

    def _estimate(
        self,
        covariance: ComplexArray,
        n_snapshots: int,
        snr_db: ArrayLike | None,
        non_finite: NDArray[np.bool_],
        non_finite_reason: str,
    ) -> DoaEstimates:
        """The shared part of :meth:`estimate`: sample covariances ``(N, M, M)``
        onwards (sets in ``non_finite`` zeroed and reported with the reason)."""
        n, m, _ = covariance.shape
        eigenvalues, eigenvectors = np.linalg.eigh(covariance)
        principal = eigenvectors[:, :, -1]
        snr = _signal_to_noise(eigenvalues, n_snapshots, snr_db, n)

        main, second = self._grid_peaks(principal)
        starts = np.concatenate([self.grid[main], self.grid[second]])
        weights = np.concatenate([principal, principal])
        tolerance = np.repeat([self.step_tolerance, SECOND_PEAK_TOLERANCE], n)
        p, s, iterations, converged = (
            v.reshape(2, n, *v.shape[1:]) for v in self._refine(starts, weights, tolerance)
        )
        has_second = second != main
        swap = has_second & (s[1] > s[0])
        if swap.any():  # the second peak is the higher one: refine it fully
            again = self._refine(
                p[1, swap], principal[swap], np.full(swap.sum(), self.step_tolerance)
            )
            p[1, swap], s[1, swap], converged[1, swap] = again[0], again[1], again[3]
            iterations[1, swap] += again[2]
            for v in (p, s, iterations, converged):
                v[:, swap] = v[::-1, swap]
        separated = has_second & (
            np.linalg.norm(p[0] - p[1], axis=-1) > self.array.first_null_radius
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(separated, (1.0 - s[0]) / (1.0 - s[1]), 0.0)

        sine = np.minimum(np.linalg.norm(p[0], axis=-1), 1.0)
        direction = np.column_stack([p[0], np.sqrt(1.0 - sine**2)])
        theta, phi = doa_from_unit_vector(direction)
        phi = np.mod(phi, 2.0 * np.pi)
        phi[phi == 2.0 * np.pi] = 0.0  # mod of a tiny negative angle rounds up
        checks = [
            (non_finite, non_finite_reason, InvalidObservationError),
            (
                np.isnan(snr),
                "one snapshot: the noise power (so the covariance) is not estimable; give snr_db",
                UnobservableError,
            ),
            (snr <= 0.0, "no signal eigenvalue above the noise floor", UnobservableError),
            (
                ratio >= self.peak_ratio_threshold,
                f"ambiguous peak: second/main MUSIC peak ratio >= {self.peak_ratio_threshold}",
                UnobservableError,
            ),
            (
                theta >= self.horizon_angle,
                f"source at the array horizon (theta >= {np.degrees(self.horizon_angle):.0f} "
                "deg): theta unobservable by a planar array",
                UnobservableError,
            ),
            (~converged[0], "peak refinement did not converge", ConvergenceError),
        ]
        valid, reason, error = _first_failures(checks, n)
        with np.errstate(invalid="ignore"):
            doa_covariance = stochastic_crb(theta, phi, snr, n_snapshots, self.array)
        nan = np.where(valid, 0.0, np.nan)
        output_snr = n_snapshots * m * snr
        # NaN output SNR (one snapshot, no SNR given) counts as below
        below = ~(output_snr >= self.threshold_output_snr)
        widening = np.where(below, self.threshold_variance_factor, 1.0)
        return DoaEstimates(
            theta=theta + nan,
            phi=phi + nan,
            covariance=doa_covariance * widening[:, None, None] + nan[:, None, None],
            valid=valid,
            reason=reason,
            error=error,
            diagnostics={
                "peak_ratio": ratio,
                "snr": snr,
                "output_snr": output_snr,
                "below_threshold": below,
                "rank_deficient": np.full(n, n_snapshots < m),
                "iterations": iterations[0].astype(float),
            },
        )

    def _grid_peaks(self, principal: ComplexArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """:meth:`_candidates` of the spectrum ``s = |e^H a|^2 / M`` (eq. 11) on the grid,
        in blocks of ``SPECTRUM_BLOCK`` sets."""
        n, m = principal.shape
        main = np.empty(n, dtype=np.intp)
        second = np.empty(n, dtype=np.intp)
        for start in range(0, n, SPECTRUM_BLOCK):
            block = slice(start, start + SPECTRUM_BLOCK)
            spectrum = np.abs(np.conj(principal[block]) @ self._grid_steering)
            np.square(spectrum, out=spectrum)
            spectrum /= m
            main[block], second[block] = self._candidates(spectrum)
        return main, second

    def _candidates(self, spectrum: Array) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Grid index of the maximum and of the highest local maximum outside its main lobe
        (the maximum itself where there is none); ties go to the lowest index.

        A local maximum is at least its highest lattice neighbour.  The highest
        point outside the main lobe almost always is one (its higher
        neighbours would have to lie in the main lobe); only the rare sets
        where it is not get all their local maxima searched.
        """
        main = np.argmax(spectrum, axis=1)
        outside = self._lattice.outside[main]
        second = np.argmax(np.where(outside, spectrum, -np.inf), axis=1)
        slope = np.flatnonzero(~self._local_maxima(spectrum, second[:, None])[:, 0])
        if slope.size:
            every = np.broadcast_to(np.arange(spectrum.shape[1]), (slope.size, spectrum.shape[1]))
            eligible = outside[slope] & self._local_maxima(spectrum[slope], every)
            second[slope] = np.argmax(np.where(eligible, spectrum[slope], -np.inf), axis=1)
        rows = np.arange(len(main))
        found = (
            outside[rows, second]
            & self._local_maxima(spectrum, second[:, None])[:, 0]
            & np.isfinite(spectrum[rows, second])
        )
        return main, np.where(found, second, main)

    def _local_maxima(self, spectrum: Array, points: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Whether grid ``points`` ``(K, P)`` of ``spectrum`` ``(K, G)`` are at least their
        highest lattice neighbour (False where NaN is involved)."""
        k, p = points.shape
        neighbours = self._lattice.neighbours[points].reshape(k, 8 * p)
        around = np.take_along_axis(spectrum, neighbours, axis=1).reshape(k, p, 8)
        return np.take_along_axis(spectrum, points, axis=1) >= around.max(axis=-1)

    def _refine(
        self, start: Array, weights: ComplexArray, tolerance: Array
    ) -> tuple[Array, Array, NDArray[np.int64], NDArray[np.bool_]]:
        """Damped Newton ascent of ``s(p)`` from ``start`` ``(K, 2)``; vectorised.

        A Newton step (Hessian negative definite) longer than the trust radius
        is shortened to it, otherwise the step is the gradient scaled to the
        radius; a step that lowers ``s`` is refused and the radius quartered,
        an accepted one doubles it (up to the grid step).  Steps never leave
        the unit disc of direction cosines; a point held on its edge by a step
        pointing outwards is a (horizon) maximum.  A Newton step shorter than
        the row's ``tolerance`` is taken without evaluating ``s`` again (the
        error after it is of the order of its square) and ends the row, as
        does an accepted edge step that moves less than ``tolerance``.
        """
        function = spectrum_function(self.array)
        real, imag = weights.real, weights.imag
        p = start.copy()
        s, g, h = evaluate_mapped(function, p, real, imag)
        s, g = s[:, 0, 0], g[:, :, 0]
        radius = np.full(len(p), self.grid_step)
        iterations = np.zeros(len(p), dtype=np.int64)
        converged = np.zeros(len(p), dtype=bool)
        for _ in range(self.max_iterations):
            active = np.flatnonzero(~converged)
            step, newton = _ascent_step(g[active], h[active], radius[active])
            final = newton & (np.linalg.norm(step, axis=-1) < tolerance[active])
            p[active[final]] = _inside_unit_disc(p[active[final]] + step[final])
            converged[active[final]] = True
            active, step = active[~final], step[~final]
            if active.size == 0:
                break
            p_old = p[active]
            candidate = _inside_unit_disc(p_old + step)
            s_c, g_c, h_c = evaluate_mapped(function, candidate, real[active], imag[active])
            s_c, g_c = s_c[:, 0, 0], g_c[:, :, 0]
            accept = s_c >= s[active] - 4.0 * np.finfo(float).eps
            rows = active[accept]
            p[rows], s[rows], g[rows], h[rows] = (
                candidate[accept],
                s_c[accept],
                g_c[accept],
                h_c[accept],
            )
            iterations[active] += 1
            radius[active] = np.where(
                accept, np.minimum(2.0 * radius[active], self.grid_step), radius[active] / 4.0
            )
            moved = np.linalg.norm(candidate - p_old, axis=-1)
            on_edge = np.linalg.norm(candidate, axis=-1) >= 1.0 - 1e-12
            converged[active] = (accept & on_edge & (moved < tolerance[active])) | (
                radius[active] < tolerance[active] ** 2
            )
        return p, s, iterations, converged


def _ascent_step(gradient: Array, hessian: Array, radius: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Newton step where ``hessian`` is negative definite, else the gradient; at most ``radius``."""
    determinant = np.linalg.det(hessian)
    newton = (hessian[:, 0, 0] < 0.0) & (determinant > 0.0)
    step = gradient.copy()
    if newton.any():
        step[newton] = -np.linalg.solve(hessian[newton], gradient[newton][..., None])[..., 0]
    length = np.linalg.norm(step, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(newton, np.minimum(1.0, radius / length), radius / length)
    scale = np.where(length > 0.0, scale, 0.0)
    return step * scale[:, None], newton


def _inside_unit_disc(p: Array) -> Array:
    """Direction cosines pulled radially back onto the closed unit disc."""
    norm = np.linalg.norm(p, axis=-1, keepdims=True)
    return np.where(norm > 1.0, p / np.maximum(norm, 1.0), p)


def _complex_sets(
    values: ArrayLike, name: str, n_elements: int, n_columns: int | None
) -> ComplexArray:
    """``values`` ``(..., M, K)`` as ``(N, M, K)`` complex, ``K = n_columns`` or, if None,
    any ``K >= 1`` (``L``); errors raise ``InvalidObservationError``."""
    try:
        x = np.asarray(values, dtype=complex)
    except (TypeError, ValueError) as exc:
        raise InvalidObservationError(f"{name} must be complex numbers: {exc}") from None
    columns = "L" if n_columns is None else n_columns
    if x.ndim < 2 or x.shape[-2] != n_elements or n_columns not in (None, x.shape[-1]):
        raise InvalidObservationError(
            f"{name} must be (..., {n_elements}, {columns}), got shape {x.shape}"
        )
    if x.shape[-1] == 0:
        raise InvalidObservationError(f"no {name} (L = 0)")
    return x.reshape(-1, n_elements, x.shape[-1])


def _zero_non_finite(sets: ComplexArray) -> tuple[ComplexArray, NDArray[np.bool_]]:
    """``sets`` with the sets holding NaN or inf zeroed, and which sets are finite."""
    finite = np.isfinite(sets).all(axis=(1, 2))
    if finite.all():
        return sets, finite
    return np.where(finite[:, None, None], sets, 0.0), finite


def _signal_to_noise(
    eigenvalues: Array, n_snapshots: int, snr_db: ArrayLike | None, n: int
) -> Array:
    """Linear SNR per element: given, or estimated from the eigenvalues of ``R``.

    Fitting the rank-one model ``a s`` to ``M L`` complex samples leaves
    ``(M - 1)(L - 1)`` complex degrees of freedom of noise, so
    ``sigma^2 = L (tr R - lambda_1) / ((M - 1)(L - 1))`` (for ``L >= M`` close
    to the mean noise eigenvalue) and ``P = tr R / M - sigma^2``.  NaN for
    ``L = 1``; ``inf`` for noise-free data.
    """
    if snr_db is not None:
        return np.broadcast_to(10.0 ** (np.asarray(snr_db, dtype=float) / 10.0), (n,)).copy()
    m = eigenvalues.shape[1]
    if n_snapshots == 1:
        return np.full(n, np.nan)
    trace = eigenvalues.sum(axis=1)
    residual = np.maximum(trace - eigenvalues[:, -1], 0.0)
    noise = n_snapshots * residual / ((m - 1) * (n_snapshots - 1))
    signal = trace / m - noise
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(noise > 0.0, signal / noise, np.where(signal > 0.0, np.inf, 0.0))


def _first_failures(
    checks: list[tuple[NDArray[np.bool_], str, type[Exception]]], n: int
) -> tuple[NDArray[np.bool_], NDArray[np.object_], NDArray[np.object_]]:
    """Validity, reason and exception class: the first failing check of each set."""
    valid = np.ones(n, dtype=bool)
    reason = np.full(n, "", dtype=object)
    error = np.full(n, None, dtype=object)
    for failed, text, exception in checks:
        new = failed & valid
        reason[new], error[new], valid[new] = text, exception, False
    return valid, reason, error
