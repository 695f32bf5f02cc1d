"""The batch smoother's optimiser: Levenberg-Marquardt driven from Python.

A Python ``CustomFactor`` inside GTSAM's optimisers receives a deep copy of the
whole ``Values`` on every call and makes a pass quadratic, so the loop runs here
and GTSAM never calls back.  Each iteration of :func:`levenberg_marquardt` on a
:class:`~attopt.solvers.smoother.problem.SmootherProblem`:

1. linearise (:meth:`~attopt.solvers.smoother.problem.SmootherProblem.linearize`:
   the built-in factors in C++, the prior's and every epoch's ``JacobianFactor``
   in numpy at the current estimate; after a rejected step the same linearisation,
   :func:`linear_system`) and add the damping ``sqrt(lambda) I`` on every variable;
2. solve (``GaussianFactorGraph.optimize``, multifrontal elimination in COLAMD
   order, linear in the pass for this chain-structured graph; with transmitter
   offsets the normal equations eliminated in time order in numpy,
   :mod:`attopt.solvers.smoother.offset_elimination`), retract (``A <- exp(-xi) A``, ``b <- b
   + d``, ``o <- o + step``);
3. evaluate every epoch at the trial point (one ``predict`` per epoch: the
   dominant cost, and the next linearisation) and accept the step if the total
   cost decreased, dividing ``lambda`` by ``lambda_factor``; else multiply it (a
   rejected step at which some block cannot be predicted, outside an antenna's
   main lobe, drops that block and is solved again instead,
   :mod:`attopt.solvers.smoother.measurement_factors`); after an accepted step
   whose bias has drifted (:meth:`~attopt.solvers.smoother.problem.SmootherProblem.bias_drifted`)
   the gyro factors are preintegrated again;
4. stop when the decrease predicted by the undamped linear model, or the
   decrease achieved by an accepted step, is at most ``absolute_tolerance +
   relative_tolerance * cost`` (converged); or when a rejected step changes
   the cost by less than the rounding level (converged); otherwise after
   ``max_iterations`` trial steps or when ``lambda`` exceeds ``max_lambda``
   (not converged, with the reason in ``message``).  ``max_iterations = 0``
   evaluates the cost at the start and returns it, not converged (the posterior
   bound's smoother at the truth, :mod:`attopt.solvers.bounds`).

Parameters: :class:`~attopt.solvers.smoother.optimiser_params.LevenbergMarquardtParams`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.solvers.smoother.conventions import (
    Array,
    attitude_key,
    bias_key,
    retract,
    step_arrays,
    to_values,
)
from attopt.solvers.smoother.measurement_factors import evaluate_factors
from attopt.solvers.smoother.offset_elimination import NormalEquations
from attopt.solvers.smoother.optimiser_params import LevenbergMarquardtParams
from attopt.solvers.smoother.problem import SmootherProblem

ROUNDING = 1e-13
"""A rejected step whose cost differs by less than this fraction is at the rounding floor."""

Step = tuple[float, float, float, float, bool]
"""One trial step: cost before, cost at the trial, decrease predicted by the linear
model, lambda, accepted."""


@dataclass(frozen=True)
class LevenbergMarquardtResult:
    """Where the loop stopped and how it got there (module docstring).

    ``attitudes``, ``bias`` ``(n, 3)``, ``offsets`` and ``values`` (the same as
    ``gtsam.Values``) are the final estimate, ``cost`` its cost and
    ``initial_cost`` the cost at the start; ``evaluations`` counts passes over all
    measurements, ``rebuilds`` the gyro factors' re-preintegrations, ``history``
    every trial :data:`Step`; ``system`` the problem linearised at ``values`` when the
    loop stopped holding it (it usually stops on the decrease that linearisation
    predicts), else ``None``: the marginals need the same linearisation.
    """

    attitudes: Rotation
    bias: Array
    offsets: Array
    values: gtsam.Values
    initial_cost: float
    cost: float
    converged: bool
    message: str
    iterations: int
    evaluations: int
    final_lambda: float
    rebuilds: int
    history: list[Step]
    system: LinearSystem | None = None

    def then(self, later: LevenbergMarquardtResult) -> LevenbergMarquardtResult:
        """``later`` (a run started where this one stopped) with both runs' counts and
        history, and this one's initial cost."""
        return replace(
            later,
            initial_cost=self.initial_cost,
            iterations=self.iterations + later.iterations,
            evaluations=self.evaluations + later.evaluations,
            rebuilds=self.rebuilds + later.rebuilds,
            history=self.history + later.history,
        )


def damped(linear: gtsam.GaussianFactorGraph, n: int, lam: float) -> gtsam.GaussianFactorGraph:
    """``linear`` with ``sqrt(lam) I`` on the attitudes and biases of ``n`` nodes."""
    out = linear.clone()
    root = np.sqrt(lam) * np.eye(3)
    zero = np.zeros(3)
    unit = gtsam.noiseModel.Unit.Create(3)
    for k in range(n):
        out.add(gtsam.JacobianFactor(attitude_key(k), root, zero, unit))
        out.add(gtsam.JacobianFactor(bias_key(k), root, zero, unit))
    return out


LinearSystem = gtsam.GaussianFactorGraph | NormalEquations
"""A problem linearised at an estimate: GTSAM's graph, or with transmitter offsets its
normal equations by blocks (module docstring, 1-2)."""


def linear_system(problem: SmootherProblem, values: gtsam.Values) -> LinearSystem:
    """``problem`` linearised at ``values`` (module docstring, 1)."""
    if problem.n_offsets:
        return problem.normal_equations(values)
    return problem.linearize(values)


def damped_step(
    problem: SmootherProblem, system: LinearSystem, lam: float
) -> tuple[Array, Array, Array, float]:
    """The step ``(xi, d, offsets)`` of ``system`` damped by ``lam`` and the decrease the
    undamped linear model predicts for it (module docstring, 1-2)."""
    if isinstance(system, NormalEquations):
        step = system.solve(lam)
        xi, d = step.nodes[:, :3], step.nodes[:, 3:]
        return xi, d, step.offsets, system.predicted_decrease(step, lam)
    solution = damped(system, problem.n, lam).optimize()
    xi, d = step_arrays(solution, problem.n)
    return xi, d, np.zeros(0), system.error(solution.scale(0.0)) - system.error(solution)


def levenberg_marquardt(
    problem: SmootherProblem,
    attitudes: Rotation,
    bias: Array,
    offsets: Array,
    params: LevenbergMarquardtParams,
) -> LevenbergMarquardtResult:
    """Minimise ``problem``'s cost from ``(attitudes, bias, offsets)`` (module docstring).

    Changes ``problem``'s epoch factors (their linearisation and dropped blocks)
    and its gyro factors (re-preintegrated about the bias).
    """
    k_huber = problem.huber_threshold
    values = to_values(attitudes, bias, offsets)
    cost = initial_cost = problem.cost(values)
    lam = params.initial_lambda
    iterations = evaluations = rebuilds = 0
    history: list[Step] = []
    converged, message = False, f"maximum iterations ({params.max_iterations}) reached"
    system = None  # the linearisation at values; kept while steps are rejected
    while params.max_iterations > 0:  # none asked for: the start evaluated, not linearised
        tolerance = params.absolute_tolerance + params.relative_tolerance * abs(cost)
        if system is None:
            system = linear_system(problem, values)
        xi, d, offset_step, predicted = damped_step(problem, system, lam)
        if predicted <= tolerance and lam <= params.initial_lambda:
            converged, message = True, "predicted decrease within tolerance"
            break
        if iterations >= params.max_iterations:
            break
        iterations += 1
        trial_offsets = offsets + offset_step
        trial_attitudes, trial_bias = retract(attitudes, xi), bias + d
        modelled = problem.modelled(trial_offsets)
        evaluations += 1
        evaluated = evaluate_factors(problem.factors, trial_attitudes, modelled)
        current = cost
        trial = np.inf
        finite = np.all(np.isfinite(xi)) and np.all(np.isfinite(d))
        if finite and np.all(np.isfinite(trial_offsets)):
            trial_values = to_values(trial_attitudes, trial_bias, trial_offsets)
            trial = problem.graph.error(trial_values) + problem.prior.cost(trial_values)
            for f, (nu, _, lost) in zip(problem.factors, evaluated, strict=True):
                trial += f.cost(nu, k_huber, lost)
                if lost.size:  # compare on the rows both points can predict
                    current += f.current_cost(k_huber, lost) - f.current_cost(k_huber)
        accepted = bool(np.isfinite(trial) and trial < current)
        history.append((float(current), float(trial), float(predicted), float(lam), accepted))
        if accepted or any(lost.size for _, _, lost in evaluated):
            system = None
        if accepted:
            attitudes, bias, values = trial_attitudes, trial_bias, trial_values
            offsets = trial_offsets
            for f, (nu, jac, lost) in zip(problem.factors, evaluated, strict=True):
                f.accept(nu, jac, lost)
            decrease, cost = current - trial, trial
            lam = max(lam / params.lambda_factor, params.min_lambda)
            if problem.bias_drifted(bias):
                problem.relinearise_bias(bias)
                rebuilds += 1
                cost = problem.cost(values)
            elif decrease <= tolerance:
                converged, message = True, "decrease within tolerance"
                break
        elif any(lost.size for _, _, lost in evaluated):
            # a block the model cannot predict at the trial point: drop it, solve again
            for f, (_, _, lost) in zip(problem.factors, evaluated, strict=True):
                f.drop(lost)
            cost = problem.cost(values)
        else:
            floor = np.isfinite(trial) and trial - current <= ROUNDING * abs(current)
            if floor and lam <= params.initial_lambda * params.lambda_factor:
                converged, message = True, "no decrease beyond the rounding level"
                break
            lam *= params.lambda_factor
            if lam > params.max_lambda:
                message = f"damping exceeded {params.max_lambda:g} without a decrease"
                break
    return LevenbergMarquardtResult(
        attitudes=attitudes,
        bias=bias,
        offsets=offsets,
        values=values,
        initial_cost=float(initial_cost),
        cost=cost,
        converged=converged,
        message=message,
        iterations=iterations,
        evaluations=evaluations,
        final_lambda=lam,
        rebuilds=rebuilds,
        history=history,
        system=system,
    )
