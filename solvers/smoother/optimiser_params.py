"""Parameters of the batch smoother's Levenberg-Marquardt loop (as GTSAM's
``LevenbergMarquardtParams``; the loop is :mod:`attopt.solvers.smoother.optimiser`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LevenbergMarquardtParams:
    """Stopping rules and damping of :func:`~attopt.solvers.smoother.optimiser.levenberg_marquardt`.

    Attributes:
        max_iterations: trial steps (each one ``predict`` per epoch) before giving
            up (GTSAM's ``maxIterations``).
        relative_tolerance, absolute_tolerance: convergence on the cost decrease
            (predicted or achieved) ``<= absolute + relative * cost``; cost units
            are half chi-square.  The predicted decrease is half the squared
            Newton decrement, ``step^T H step / 2``: at the default 1e-3 the
            remaining step is at most 0.045 posterior standard deviations in
            Mahalanobis norm over the whole pass.
        initial_lambda, lambda_factor, max_lambda, min_lambda: the damping
            ``lambda I`` starts at ``initial_lambda``, is divided by
            ``lambda_factor`` after an accepted step (not below ``min_lambda``)
            and multiplied by it after a rejected one; above ``max_lambda`` the
            loop gives up (GTSAM's ``lambdaInitial``, ``lambdaFactor``,
            ``lambdaUpperBound``, ``lambdaLowerBound``).
    """

    max_iterations: int = 30
    relative_tolerance: float = 1e-10
    absolute_tolerance: float = 1e-3
    initial_lambda: float = 1e-6
    lambda_factor: float = 10.0
    max_lambda: float = 1e8
    min_lambda: float = 1e-12

    def __post_init__(self) -> None:
        if self.max_iterations < 0 or self.lambda_factor <= 1 or self.initial_lambda <= 0:
            raise ValueError("need max_iterations >= 0, lambda_factor > 1, initial_lambda > 0")
        if not (self.relative_tolerance >= 0 and self.absolute_tolerance >= 0):
            raise ValueError("the tolerances must be non-negative")
        if not 0 < self.min_lambda <= self.initial_lambda <= self.max_lambda:
            raise ValueError("need 0 < min_lambda <= initial_lambda <= max_lambda")
