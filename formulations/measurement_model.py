"""A measurement's model written once, symbolically: the hook every generic estimator uses.

:meth:`attopt.formulations.attitude_measurement.AttitudeMeasurement.symbolic`
returns a :class:`SymbolicModel`: the model function ``h(A, *parameters)``
(written with :mod:`attopt.formulations.symbolic`, a ``3 x 3`` attitude and
parameter matrices in, a column out), the parameters' values, which of its
outputs are measured (``rows``) and the measurement's innovation
``nu(z, h)`` in CasADi.  From it

* :meth:`SymbolicModel.evaluate` gives values and body-frame Jacobians by
  CasADi AD (:func:`attopt.formulations.attitude_model.attitude_model_function`),
  the default ``predict`` of a measurement type (the filters and smoothers);
* :func:`attopt.formulations.map_problem.map_loss` builds the MAP loss of a
  snapshot of any mix of types (the ``map_nlp`` estimator);
* :meth:`SymbolicModel.innovation_values` evaluates the innovation on numpy
  arrays, the default ``innovation`` of a measurement type.

So a new measurement type writes its model once and gets the filters, the
smoother, the MAP NLP and the Cramer-Rao bound (:mod:`attopt.solvers.bounds`).

The model function and the innovation must be module-level (or cached)
callables: compiled CasADi functions and NLPs are cached by them and by the
parameter shapes.

Innovations (CasADi, elementwise unless stated):

* :func:`difference`: ``z - h``;
* :func:`wrapped_difference`: ``z - h`` with the rows where ``wrapped`` is 1
  wrapped into ``(-pi, pi]`` as ``atan2(sin d, cos d)`` (smooth in ``d``);
* :func:`geodesic_difference`: per unit vector (3-row block) the geodesic
  difference ``theta p / |p|`` of
  :class:`~attopt.formulations.attitude_measurement.VectorMeasurement`,
  written as ``p atan2(|p|, c) / |p|`` with ``c = z . u``, ``u = h / |h|``
  and ``p = z - c u``, and for ``|p| < 1e-6 c`` as the series
  ``p (1 - |p|^2 / (3 c^2)) / c``, so that it stays differentiable at
  ``p = 0`` (a noise-free optimum).  A reversed vector (``c < 0`` with ``|p|``
  that small, antipodal to rounding) has no direction of difference: it gets
  ``pi`` times a unit vector perpendicular to ``u``, the limit of the
  difference's size, so that the loss there is the largest, not zero.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_model import attitude_model_function, evaluate_at_attitudes
from attopt.formulations.kernels import evaluate_mapped

Array = NDArray[np.float64]

_SERIES_BELOW = 1e-6
"""``|p| / c`` below which the geodesic difference uses its series."""


def difference(z: Any, h: Any) -> Any:
    """``z - h``."""
    return z - h


def wrapped_difference(z: Any, h: Any, wrapped: Any) -> Any:
    """``z - h``, wrapped into ``(-pi, pi]`` where ``wrapped`` is 1 (module docstring)."""
    d = z - h
    return d + wrapped * (ca.atan2(ca.sin(d), ca.cos(d)) - d)


def geodesic_difference(z: Any, h: Any) -> Any:
    """Geodesic difference of each measured unit vector from its prediction (module docstring).

    ``z`` and ``h`` are ``3 k x 1`` columns of stacked vectors; so is the result.
    """
    k = z.numel() // 3
    measured = ca.reshape(z, 3, k)
    predicted = ca.reshape(h, 3, k)
    unit = predicted / ca.repmat(ca.sqrt(ca.sum1(predicted**2)), 3, 1)
    cosine = ca.sum1(measured * unit)
    perpendicular = measured - unit * ca.repmat(cosine, 3, 1)
    square = ca.sum1(perpendicular**2)
    sine = ca.sqrt(ca.fmax(square, 1e-300))
    exact = ca.atan2(sine, cosine) / sine
    series = (1.0 - square / (3.0 * cosine**2)) / cosine
    near = square <= (_SERIES_BELOW * cosine) ** 2
    ratio = ca.if_else(near * (cosine > 0), series, exact)
    regular = perpendicular * ca.repmat(ratio, 3, 1)
    reversed_ = ca.repmat(near * (cosine < 0), 3, 1)
    return ca.vec(ca.if_else(reversed_, np.pi * _any_perpendicular(unit), regular))


def _any_perpendicular(unit: Any) -> Any:
    """A unit vector perpendicular to each column of ``unit`` (``3 x k``): its cross product
    with the coordinate axis it is least aligned with, normalised."""
    x, y, z = unit[0, :], unit[1, :], unit[2, :]
    zero = ca.DM.zeros(1, unit.size2())
    with_x = ca.vertcat(zero, z, -y)  # u x e_x, |.|^2 = 1 - x^2
    with_y = ca.vertcat(-z, zero, x)  # u x e_y
    with_z = ca.vertcat(y, -x, zero)  # u x e_z
    best_xy = ca.if_else(ca.repmat(x**2 <= y**2, 3, 1), with_x, with_y)
    smallest_xy = ca.fmin(x**2, y**2)
    cross = ca.if_else(ca.repmat(z**2 < smallest_xy, 3, 1), with_z, best_xy)
    return cross / ca.repmat(ca.sqrt(ca.sum1(cross**2)), 3, 1)


def _matrix(value: ArrayLike) -> Array:
    """A parameter as a 2-D float array: scalars ``(1, 1)``, vectors columns ``(n, 1)``."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        return a.reshape(1, 1)
    if a.ndim == 1:
        return a.reshape(-1, 1)
    if a.ndim != 2:
        raise ValueError(f"model parameters are matrices, got shape {a.shape}")
    return a


def _shapes(values: Sequence[Array]) -> tuple[tuple[int, int], ...]:
    return tuple((int(v.shape[0]), int(v.shape[1])) for v in values)


@lru_cache(maxsize=64)
def _innovation_function(
    innovation: Callable[..., Any], size: int, shapes: tuple[tuple[int, int], ...]
) -> ca.Function:
    z, h = ca.SX.sym("z", size), ca.SX.sym("h", size)
    parameters = [ca.SX.sym(f"p{i}", *shape) for i, shape in enumerate(shapes)]
    return ca.Function(innovation.__name__, [z, h, *parameters], [innovation(z, h, *parameters)])


@dataclass(frozen=True, eq=False)
class SymbolicModel:
    """``h = model(A, *parameters)[rows]`` and its innovation ``nu(z, h, *innovation_parameters)``.

    Attributes:
        model: ``(A, *parameters) -> h`` (a column), written with
            :mod:`attopt.formulations.symbolic`; module-level or cached.
        parameters: the parameter values (scalars and vectors become
            ``(1, 1)`` and ``(n, 1)`` matrices).
        rows: the model outputs that are measured, in order (``None``: all).
        innovation: ``(z, h, *innovation_parameters) -> nu`` in CasADi
            (:func:`difference`, :func:`wrapped_difference`, :func:`geodesic_difference`).
        innovation_parameters: values of the innovation's extra parameters.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import SymbolicModel
        >>> def body_vector(attitude, reference):  # h(A) = A r, written once
        ...     return attitude @ reference
        >>> model = SymbolicModel(body_vector, (np.array([1.0, 0.0, 0.0]),))
        >>> h, jacobian = model.evaluate(Rotation.identity())
        >>> h.tolist(), (jacobian[0].round(12) + 0.0).tolist()  # d(A r)/d(delta) = -[A r x]
        ([[1.0, 0.0, 0.0]], [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    """

    model: Callable[..., Any]
    parameters: tuple[Array, ...] = ()
    rows: tuple[int, ...] | None = None
    innovation: Callable[..., Any] = difference
    innovation_parameters: tuple[Array, ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", tuple(_matrix(p) for p in self.parameters))
        object.__setattr__(
            self, "innovation_parameters", tuple(_matrix(p) for p in self.innovation_parameters)
        )
        if self.rows is not None:
            object.__setattr__(self, "rows", tuple(int(r) for r in self.rows))

    @property
    def shapes(self) -> tuple[tuple[int, int], ...]:
        """Shapes of :attr:`parameters`."""
        return _shapes(self.parameters)

    @property
    def innovation_shapes(self) -> tuple[tuple[int, int], ...]:
        """Shapes of :attr:`innovation_parameters`."""
        return _shapes(self.innovation_parameters)

    @property
    def function(self) -> ca.Function:
        """``(A, *parameters) -> (h, dh/dv)`` of every model output (cached)."""
        return attitude_model_function(self.model, self.shapes)

    @property
    def structure(self) -> tuple[Any, ...]:
        """What compiled problems built from this model depend on (not the values)."""
        return (self.model, self.shapes, self.rows, self.innovation, self.innovation_shapes)

    def outputs(self, h: Any) -> Any:
        """The measured outputs :attr:`rows` of the model's ``h`` (numpy ``(..., n)`` or CasADi)."""
        if self.rows is None:
            return h
        if isinstance(h, ca.SX | ca.MX | ca.DM):
            return h[list(self.rows)]
        return h[..., list(self.rows)]

    def evaluate_outputs(self, attitude: Rotation) -> tuple[Array, Array]:
        """Every model output ``(N, n)`` and its body-frame Jacobian ``(N, n, 3)`` (AD)."""
        return evaluate_at_attitudes(self.function, attitude.as_matrix(), *self.parameters)

    def evaluate(self, attitude: Rotation) -> tuple[Array, Array]:
        """Values ``(N, m)`` of :attr:`rows` and body-frame Jacobians ``(N, m, 3)`` (AD)."""
        h, jacobian = self.evaluate_outputs(attitude)
        if self.rows is None:
            return h, jacobian
        rows = list(self.rows)
        return h[:, rows], jacobian[:, rows]

    def innovation_values(self, z: ArrayLike, predicted: ArrayLike) -> Array:
        """The innovation of predictions ``(..., m)`` (numpy, by the CasADi definition)."""
        z = np.asarray(z, dtype=float).ravel()
        predicted = np.asarray(predicted, dtype=float)
        if z.size == 0:
            return np.empty(predicted.shape)
        function = _innovation_function(self.innovation, z.size, self.innovation_shapes)
        flat = predicted.reshape(-1, z.size)
        (nu,) = evaluate_mapped(function, z, flat, *self.innovation_parameters)
        return nu.reshape(predicted.shape)
