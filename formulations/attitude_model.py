"""Attitude-model machinery shared by every measurement model: increment and AD.

A measurement model ``h(A, params)`` is written once with
:mod:`attopt.formulations.symbolic`.  Solvers vary the attitude as ``A = C(v) A_ref``
(:func:`increment_matrix`, Liu et al. 2023 eq. 28) and need ``h`` and ``dh/dv`` at
``v = 0``: the Jacobian with respect to the body-frame attitude error
(``docs/conventions.md``).  :func:`attitude_model_function` builds that pair
by CasADi automatic differentiation and :func:`evaluate_at_attitudes`
evaluates it at a stack of attitudes in one call into compiled code
(:mod:`attopt.formulations.kernels`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.kernels import evaluate_mapped
from attopt.formulations.symbolic import namespace_of

Array = NDArray[np.float64]


def increment_matrix(v: Any) -> Any:
    """``C(v)``: rotation matrix with modified Rodrigues parameters ``p = v / 4``.

    ``C = I + (8 [p x]^2 + 4 (1 - |p|^2) [p x]) / (1 + |p|^2)^2``, which is
    ``Rotation.from_mrp(v / 4).as_matrix()``: the rotation by
    ``4 arctan(|v| / 4)`` about ``v``, i.e. ``v`` minus ``O(|v|^3)``.  Four times
    the MRPs is the attitude error vector of Liu et al. 2023 eq. 28.  Rational in
    ``v`` (no ``sinc``), exactly orthogonal, smooth at ``v = 0``.  numpy: ``v``
    is ``(..., 3)``, the result ``(..., 3, 3)``; CasADi: ``v`` is ``3 x 1``.
    """
    xp = namespace_of(v)
    p = [c / 4.0 for c in xp.components(v)]
    norm2 = p[0] ** 2 + p[1] ** 2 + p[2] ** 2
    scale = 1.0 / (1.0 + norm2) ** 2
    cross = [[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]]
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    rows = [
        [
            eye[i][j]
            + 8.0 * scale * (p[i] * p[j] - norm2 * eye[i][j])
            + 4.0 * scale * (1.0 - norm2) * cross[i][j]
            for j in range(3)
        ]
        for i in range(3)
    ]
    return xp.matrix(rows)


@lru_cache(maxsize=32)
def attitude_model_function(
    model: Callable[..., Any], parameter_shapes: tuple[tuple[int, int], ...]
) -> ca.Function:
    """``(A, *params) -> (h, dh/dv)`` at ``v = 0`` of ``h = model(C(v) A, *params)``, by CasADi AD.

    ``model`` takes a symbolic ``3 x 3`` attitude and parameters of
    ``parameter_shapes`` and returns a column ``h`` (``m x 1``).  The
    derivative is taken with ``v`` symbolic and then ``v = 0`` is substituted,
    which lets CasADi fold the increment away (about 2.6 times fewer
    instructions for the SNR model).
    """
    v = ca.SX.sym("v", 3)
    attitude = ca.SX.sym("attitude", 3, 3)
    parameters = [ca.SX.sym(f"p{i}", *shape) for i, shape in enumerate(parameter_shapes)]
    h = model(increment_matrix(v) @ attitude, *parameters)
    at_zero = ca.substitute([h, ca.jacobian(h, v)], [v], [ca.DM.zeros(3)])
    return ca.Function(model.__name__, [attitude, *parameters], at_zero)


def evaluate_at_attitudes(
    function: ca.Function, attitude_matrices: ArrayLike, *parameters: ArrayLike
) -> tuple[Array, Array]:
    """``h`` ``(N, m)`` and ``dh/dv`` ``(N, m, 3)`` of ``function`` at ``N`` attitudes.

    ``function`` is ``(A, *params) -> (h[m], J[m x 3])`` as built by
    :func:`attitude_model_function`; ``attitude_matrices`` is ``(N, 3, 3)``;
    each parameter is either one value in the shape of the function's input
    (shared by every attitude) or ``N`` such values stacked on a leading axis.
    One call into the compiled kernel
    (:func:`attopt.formulations.kernels.evaluate_mapped`).
    """
    matrices = np.asarray(attitude_matrices, dtype=float).reshape(-1, 3, 3)
    h, jacobian = evaluate_mapped(function, matrices, *parameters)
    return h.reshape(h.shape[0], -1), jacobian
