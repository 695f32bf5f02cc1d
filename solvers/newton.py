"""Vectorised Newton-Raphson for the largest root of quartic characteristic equations.

Shared by QUEST and FOAM (Cilden Guler et al. 2017 secs. 2.5-2.6): both start from
``lambda_0 = sum_i a_i``, which bounds ``lambda_max`` from above.  All roots
of these polynomials are real (they are characteristic polynomials of
symmetric matrices), so from above the largest root Newton's steps decrease
monotonically; iteration stops when the step is below ``rtol * lambda_0`` or
when rounding makes the step change sign (the root is then as accurate as the
polynomial's evaluation allows).  A row still stepping after
``max_iterations`` has not converged.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

RTOL = 1e-14
"""Steps below ``RTOL * lambda_0`` end the iteration."""
MAX_ITERATIONS = 50
"""A row still stepping after this many iterations has not converged."""


def largest_root_newton(
    coefficients: NDArray[np.float64],
    start: NDArray[np.float64],
    *,
    rtol: float = RTOL,
    max_iterations: int = MAX_ITERATIONS,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """Newton iterations on ``sum_k c_k x^(4-k)`` per row of ``coefficients`` ``(N, 5)``.

    Returns the root, the iteration count of each row and whether it converged.
    """
    c = coefficients
    derivative = c[:, :4] * np.array([4.0, 3.0, 2.0, 1.0])
    x = np.array(start, dtype=float)
    iterations = np.zeros(x.shape, dtype=np.int64)
    active = np.ones(x.shape, dtype=bool)
    scale = np.abs(start)
    for _ in range(max_iterations):
        if not active.any():
            break
        xa = x[active]
        f = _horner(c[active], xa)
        df = _horner(derivative[active], xa)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(df != 0.0, f / df, 0.0)
        x[active] = xa - step
        iterations[active] += 1
        done = ~(np.abs(step) > rtol * scale[active]) | (step < 0.0)
        active[np.flatnonzero(active)[done]] = False
    return x, iterations, ~active


def _horner(coefficients: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Evaluate each row's polynomial (highest power first) at its ``x``."""
    value = coefficients[:, 0].copy()
    for k in range(1, coefficients.shape[1]):
        value = value * x + coefficients[:, k]
    return value
