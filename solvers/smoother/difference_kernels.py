"""The arithmetic of the innovation's central differences compiled with numba.

Every epoch factor of the smoothers differentiates its innovation ``nu = innovation(h)``
with respect to the predictions by central differences
(:func:`attopt.solvers.smoother.measurement_factors.innovation_jacobian`): one
perturbation per row position within a block, then the chain rule with the model's
Jacobian.  Around the one call of the measurement's ``innovation`` (which is the
measurement's own), numpy needs about a dozen small array calls per epoch, 35-40 us for
two unit vectors, on every factor at the start, at every trial point and at the
solution; here they are two calls of machine code (:func:`perturbed_predictions`,
:func:`chain_rule`).  Written with numba for that per-call cost.  The numpy expressions
of ``innovation_jacobian`` (``ATTOPT_KERNELS=interpreted``) stay the reference; the two
agree to round-off (``tests/test_smoother_pieces.py``).

Example::

    >>> import numpy as np
    >>> perturbed, step = perturbed_predictions(np.array([2.0, 0.5]), np.array([0, 1]), 2, 1e-6)
    >>> perturbed.shape, step.tolist()
    ((4, 2), [2e-06, 1e-06])
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations.kernels import first_call, register_warm_up

Array = NDArray[np.float64]

_jit = njit(cache=True, error_model="numpy")
"""numba's compilation, cached on disk, with numpy's float semantics."""


def perturbed_predictions(
    predicted: Array, position: NDArray[np.intp], size: int, relative_step: float
) -> tuple[Array, Array]:
    """``(2 size, m)`` predictions, row ``2 p + s`` with every row at position ``p`` of its
    block moved by ``+step`` (``s = 0``) or ``-step`` (``s = 1``), and the steps ``(m,)``,
    ``relative_step * max(1, |h|)`` (NaN where ``h`` is)."""
    return first_call(
        _perturbed_predictions,
        "the innovation differences' perturbations",
        np.ascontiguousarray(predicted, dtype=float),
        np.ascontiguousarray(position),
        size,
        relative_step,
    )


@_jit
def _perturbed_predictions(
    predicted: Array, position: NDArray[np.intp], size: int, relative_step: float
) -> tuple[Array, Array]:
    """:func:`perturbed_predictions`' loop."""
    m = predicted.shape[0]
    step = np.empty(m)
    out = np.empty((2 * size, m))
    for i in range(m):
        magnitude = abs(predicted[i])
        step[i] = relative_step * (magnitude if magnitude > 1.0 or magnitude != magnitude else 1.0)
        for r in range(2 * size):
            out[r, i] = predicted[i] + 0.0
        out[2 * position[i], i] = predicted[i] + step[i]
        out[2 * position[i] + 1, i] = predicted[i] + -step[i]
    return out, step


def chain_rule(
    innovations: Array,
    step: Array,
    valid: NDArray[np.bool_],
    source: NDArray[np.intp],
    jacobian: Array,
) -> Array:
    """``-d nu / d delta`` ``(m, 3)`` from the innovations ``(2 size, m)`` at
    :func:`perturbed_predictions` and the model's Jacobian ``(m, 3)``: per row ``i``,
    ``-sum_r (d nu_i / d h_j) J_j`` over the rows ``j = source[i, r]`` of its block
    (``valid``), ``d nu_i / d h_j`` the central difference at ``j``'s position."""
    return first_call(
        _chain_rule,
        "the innovation differences' chain rule",
        np.ascontiguousarray(innovations, dtype=float),
        np.ascontiguousarray(step, dtype=float),
        np.ascontiguousarray(valid),
        np.ascontiguousarray(source),
        np.ascontiguousarray(jacobian, dtype=float),
    )


@_jit
def _chain_rule(
    innovations: Array,
    step: Array,
    valid: NDArray[np.bool_],
    source: NDArray[np.intp],
    jacobian: Array,
) -> Array:
    """:func:`chain_rule`'s loop."""
    m, size = valid.shape
    out = np.empty((m, jacobian.shape[1]))
    for i in range(m):
        for k in range(jacobian.shape[1]):
            total = 0.0
            for r in range(size):
                if valid[i, r]:
                    j = source[i, r]
                    difference = innovations[2 * r, i] - innovations[2 * r + 1, i]
                    total += difference / (2.0 * step[j]) * jacobian[j, k]
            out[i, k] = -total
    return out


# Warm-ups (attopt.formulations.kernels.WARM_UPS): one block of two rows.
register_warm_up(
    "smoother.perturbations",
    lambda: perturbed_predictions(np.ones(2), np.array([0, 1], np.intp), 2, 1e-6),
)
register_warm_up(
    "smoother.chain_rule",
    lambda: chain_rule(
        np.zeros((4, 2)),
        np.ones(2),
        np.ones((2, 2), bool),
        np.array([[0, 1], [0, 1]], np.intp),
        np.zeros((2, 3)),
    ),
)
