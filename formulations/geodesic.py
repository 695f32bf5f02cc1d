"""The geodesic difference of measured unit vectors from predicted ones, compiled with numba.

Every filter update, smoother factor and sigma point of a unit-vector measurement
evaluates :meth:`attopt.formulations.attitude_measurement.VectorMeasurement.innovation`:
for each measured ``z`` and predicted ``h`` (not necessarily unit), with ``u = h / |h|``,
``c = z . u``, ``p = z - c u`` and ``s = |p|``,

    nu = atan2(s, c) p / s,

the tangent vector at ``u`` towards ``z`` whose length is the angle between them
(:func:`attopt.formulations.measurement_model.geodesic_difference`, the symbolic
definition); ``0`` where ``s = 0`` and ``c > 0``, NaN where the vectors are
opposite (``s = 0``, ``c <= 0``) or not finite.  A main-job pass calls it about 60,000
times on a few vectors each; in numpy each call is a dozen array operations, about 25 us,
here one loop of machine code (about 1 us).  Written with numba because the per-call
cost of a CasADi kernel is higher than numpy's.  :func:`geodesic_reference`, the numpy
path (``ATTOPT_KERNELS=interpreted``), is the reference; the two agree to round-off
(``tests/test_geodesic.py``).

Example::

    >>> import numpy as np
    >>> z = np.array([0.0, 1.0, 0.0])
    >>> geodesic_rows(np.array([[1.0, 0.0, 0.0]]), z).round(6).tolist()  # 90 deg towards +y
    [[0.0, 1.570796, 0.0]]
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations.kernels import first_call, register_warm_up

Array = NDArray[np.float64]


def geodesic_rows(predicted: Array, z: Array) -> Array:
    """``(n, 3 k)`` geodesic differences of the ``k`` stacked measured vectors ``z``
    ``(3 k,)`` from each row of ``predicted`` ``(n, 3 k)`` (module docstring)."""
    return first_call(
        _geodesic_rows,
        "the unit vectors' geodesic difference",
        np.ascontiguousarray(predicted, dtype=float),
        np.ascontiguousarray(z, dtype=float),
    )


def geodesic_reference(predicted: Array, z: Array) -> Array:
    """The numpy reference of :func:`geodesic_rows` (same arguments and result)."""
    # the norms as ndarray sums (np.linalg.norm's values, bit for bit) and the division
    # only where the sine is positive
    h = predicted.reshape(predicted.shape[0], -1, 3)
    unit = h / np.sqrt((h * h).sum(axis=-1, keepdims=True))
    measured = z.reshape(-1, 3)
    cosine = (measured * unit).sum(axis=-1, keepdims=True)
    perpendicular = measured - cosine * unit
    sine = np.sqrt((perpendicular * perpendicular).sum(axis=-1, keepdims=True))
    positive = sine > 0
    geodesic = np.arctan2(sine, cosine) * perpendicular
    np.divide(geodesic, sine, out=geodesic, where=positive)
    if not positive.all():  # along the prediction: 0; opposite or not finite: NaN
        geodesic = np.where(positive, geodesic, np.where(cosine > 0, 0.0, np.nan))
    return geodesic.reshape(predicted.shape)


@njit(cache=True, error_model="numpy")
def _geodesic_rows(predicted: Array, z: Array) -> Array:
    """:func:`geodesic_rows`' loop, in the numpy path's order of operations."""
    n, m = predicted.shape
    out = np.empty((n, m))
    for i in range(n):
        for j in range(0, m, 3):
            h0, h1, h2 = predicted[i, j], predicted[i, j + 1], predicted[i, j + 2]
            norm = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
            u0, u1, u2 = h0 / norm, h1 / norm, h2 / norm
            cosine = z[j] * u0 + z[j + 1] * u1 + z[j + 2] * u2
            p0, p1, p2 = z[j] - cosine * u0, z[j + 1] - cosine * u1, z[j + 2] - cosine * u2
            sine = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
            if sine > 0.0:
                angle = math.atan2(sine, cosine)
                out[i, j], out[i, j + 1], out[i, j + 2] = (
                    angle * p0 / sine,
                    angle * p1 / sine,
                    angle * p2 / sine,
                )
            else:  # along the prediction: 0; opposite or not finite: NaN
                along = 0.0 if cosine > 0.0 else math.nan
                out[i, j], out[i, j + 1], out[i, j + 2] = along, along, along
    return out


register_warm_up("vectors.geodesic", lambda: geodesic_rows(np.array([[1.0, 0.0, 0.0]]), np.ones(3)))
