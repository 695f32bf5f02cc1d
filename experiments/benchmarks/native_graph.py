"""The batch smoother against GTSAM's own C++ optimiser on the same graph.

One trial of the default ``wahba-mag-sun`` setting (the 6000 s pass: Sun and magnetometer
unit vectors at 1 Hz, the eclipse, the gyro at 10 Hz), solved twice from the same start
(the RTS pass over the MEKF):

* ``fg_batch`` (:class:`attopt.solvers.smoother.BatchSmoother`), its report's stages:
  ``factors`` (the problem and its measurement factors prepared at the start),
  ``optimisation`` (attopt's Levenberg-Marquardt, each step's linear system eliminated by
  GTSAM) and ``marginals`` (METIS Bayes tree, per-node ``6 x 6`` joints);
* the reference, measured in the same run: the same nodes and the same gyro factors
  (:func:`attopt.solvers.smoother.gyro_factors.gyro_graph`: ``AHRSFactor`` and
  ``BetweenFactorVector``), GTSAM's native ``AttitudeFactorRot3`` for each unit vector
  (``nRef`` the reference direction, ``bMeasured`` the body measurement, isotropic
  2-sigma on ``Unit3``'s tangent), ``PriorFactorRot3`` and ``PriorFactorVector`` for the
  prior (its attitude and bias blocks; the smoother whitens the two jointly with their
  cross terms), optimised by ``gtsam.LevenbergMarquardtOptimizer`` (the smoother's
  iteration limit and relative tolerance) and marginalised as the smoother does: the
  graph linearised at the solution, eliminated into a Bayes tree in METIS order, one
  joint ``[attitude, bias]`` query per node (``gtsam.Marginals``, which orders by
  COLAMD, took 3.0 s here against this path's 0.4 s).

The two solutions differ by design: the smoother's residual is the geodesic angle
between predicted and measured direction, ``AttitudeFactorRot3``'s its sine (via
``Unit3``'s tangent); the largest attitude difference is printed.  Times are medians
(min-max) over ``--runs`` repeats in one process, after a warm-up solve of each.

Run with ``python -m attopt.experiments.benchmarks.native_graph [--runs 3]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.registry import get_experiment
from attopt.experiments.sweep.seeding import trial_seed
from attopt.experiments.wahba_mag_sun.experiment import (
    WahbaMagSunParameters,
    filter_inputs,
    geometry_of,
    simulate_pass,
)
from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    ReferencedMeasurement,
    VectorMeasurement,
)
from attopt.formulations.conventions import attitude_error
from attopt.formulations.passes import Pass
from attopt.solvers.filters.common import GyroPass, gyro_pass
from attopt.solvers.registry import estimator
from attopt.solvers.results import Track
from attopt.solvers.smoother import BatchSmoother
from attopt.solvers.smoother.conventions import attitude, attitude_key, bias_key, rot3
from attopt.solvers.smoother.gyro_factors import gyro_graph, gyro_intervals
from attopt.solvers.smoother.initial import given_start, node_values
from attopt.solvers.smoother.problem import pass_nodes

Array = NDArray[np.float64]

STAGES = ("factors", "optimisation", "marginals")


@dataclass(frozen=True)
class Solve:
    """One solve's stage times (s), its attitudes (one per node) and iterations."""

    seconds: dict[str, float]
    attitudes: Rotation
    iterations: int


def trial_pass(duration_s: float | None = None) -> tuple[Pass, Track]:
    """The default setting's trial 0 with its gyro (its first ``duration_s``, default the
    whole pass), and the RTS start both solves share."""
    experiment = get_experiment("wahba-mag-sun")
    setting = experiment.grid(experiment.parameters)[0]
    if duration_s is not None:
        setting = {**setting, "duration_s": duration_s}
    parameters = WahbaMagSunParameters.model_validate(setting)
    seed = trial_seed(0, 0, 0)
    vectors = simulate_pass(geometry_of(parameters), seed, parameters)
    truth, inputs = filter_inputs(parameters, seed)
    pass_ = inputs.gyro_pass(truth, vectors.pass_.snapshots).pass_
    forward = estimator("mekf").solve(pass_)
    return pass_, estimator("rts").solve(pass_, initial=forward)


def attopt_solve(smoother: BatchSmoother, pass_: Pass, start: Track) -> Solve:
    """``fg_batch`` from ``start``: its report's stage times."""
    track = smoother.solve(pass_, initial=start)
    seconds = {stage: track.report.seconds[stage] for stage in STAGES}
    return Solve(seconds, Rotation.from_quat(track.quaternion), track.report.iterations)


def native_graph(
    smoother: BatchSmoother, inputs: GyroPass, start: Track, pass_: Pass
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The reference graph (module docstring) and its start values."""
    values = node_values(given_start(start, pass_), inputs)
    nodes, offset = pass_nodes(inputs.gyro)
    intervals = gyro_intervals(nodes, inputs.gyro, inputs.model, smoother.filter.max_gyro_gap_s)
    graph = gyro_graph(intervals, inputs.gyro, values.bias)
    prior = inputs.prior
    graph.add(
        gtsam.PriorFactorRot3(
            attitude_key(0),
            rot3(prior.attitude),
            gtsam.noiseModel.Gaussian.Covariance(prior.covariance[:3, :3]),
        )
    )
    graph.add(
        gtsam.PriorFactorVector(
            bias_key(0), prior.bias, gtsam.noiseModel.Gaussian.Covariance(prior.covariance[3:, 3:])
        )
    )
    for k, measurement in enumerate(inputs.measurements):
        if measurement is None:
            continue
        vectors, reference = _inertial(measurement)
        body = vectors.z.reshape(-1, 3)
        for b, r, sigma in zip(body, reference, vectors.sigma, strict=True):
            graph.add(
                gtsam.AttitudeFactorRot3(
                    attitude_key(k + offset),
                    gtsam.Unit3(r),
                    gtsam.noiseModel.Isotropic.Sigma(2, float(sigma)),
                    gtsam.Unit3(b),
                )
            )
    initial = gtsam.Values()
    for n in range(nodes.size):
        initial.insert(attitude_key(n), rot3(values.attitudes[n]))
        initial.insert(bias_key(n), np.asarray(values.bias[n], dtype=float))
    return graph, initial


def _inertial(measurement: AttitudeMeasurement) -> tuple[VectorMeasurement, Array]:
    """The unit vectors of ``measurement`` and their inertial reference directions (the
    pass's measurements are orbit-frame vectors re-expressed for the inertial attitude:
    ``b = A_bo r_o = A_bi (F r_o)``, :class:`ReferencedMeasurement`)."""
    if isinstance(measurement, ReferencedMeasurement):
        inner = measurement.inner
        if isinstance(inner, VectorMeasurement):
            return inner, measurement.frame_inverse.apply(inner.reference)
    elif isinstance(measurement, VectorMeasurement):
        return measurement, measurement.reference
    raise TypeError(f"the native graph takes unit vectors, not {type(measurement).__name__}")


def native_solve(smoother: BatchSmoother, pass_: Pass, start: Track) -> Solve:
    """The reference: graph built, optimised and marginalised by GTSAM (module docstring)."""
    inputs = gyro_pass(pass_, smoother, smoother.filter)
    begin = time.perf_counter()
    graph, initial = native_graph(smoother, inputs, start, pass_)
    built = time.perf_counter()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(smoother.optimiser.max_iterations)
    params.setRelativeErrorTol(smoother.optimiser.relative_tolerance)
    optimiser = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimiser.optimize()
    optimised = time.perf_counter()
    linear = graph.linearize(result)
    tree = linear.eliminateMultifrontal(gtsam.Ordering.MetisGaussianFactorGraph(linear))
    n = initial.size() // 2
    for node in range(n):
        tree.jointMarginalCovariance([attitude_key(node), bias_key(node)])
    done = time.perf_counter()
    attitudes = Rotation.concatenate([attitude(result.atRot3(attitude_key(k))) for k in range(n)])
    seconds = {
        "factors": built - begin,
        "optimisation": optimised - built,
        "marginals": done - optimised,
    }
    return Solve(seconds, attitudes, optimiser.iterations())


def run(runs: int = 3, duration_s: float | None = None) -> tuple[list[Solve], list[Solve], float]:
    """``runs`` timed solves of each (after one warm-up each) and the largest attitude
    difference (deg) between the two solutions at the pass's epochs."""
    pass_, start = trial_pass(duration_s)
    smoother = estimator("fg_batch")
    attopt_solve(smoother, pass_, start)
    native_solve(smoother, pass_, start)
    ours, native = [], []
    for _ in range(runs):
        ours.append(attopt_solve(smoother, pass_, start))
        native.append(native_solve(smoother, pass_, start))
    offset = len(native[0].attitudes) - len(ours[0].attitudes)
    difference = attitude_error(ours[0].attitudes, native[0].attitudes[offset:])
    return ours, native, float(np.degrees(np.abs(difference).max()))


def _spread(values: list[float]) -> str:
    return f"{np.median(values):.2f} ({min(values):.2f}-{max(values):.2f})"


def format_table(ours: list[Solve], native: list[Solve], difference_deg: float) -> str:
    """Stages and total, median (min-max) seconds, and the ratio of the medians."""
    lines = [
        "| stage | fg_batch (s) | GTSAM native (s) | fg_batch / native |",
        "|---|---|---|---|",
    ]
    for stage in (*STAGES, "total"):

        def seconds(solve: Solve, stage: str = stage) -> float:
            return sum(solve.seconds.values()) if stage == "total" else solve.seconds[stage]

        a = [seconds(s) for s in ours]
        b = [seconds(s) for s in native]
        lines.append(
            f"| {stage} | {_spread(a)} | {_spread(b)} | {np.median(a) / np.median(b):.2f} |"
        )
    lines.append("")
    lines.append(
        f"Iterations: fg_batch {ours[0].iterations}, native {native[0].iterations}; "
        f"largest attitude difference {difference_deg:.1e} deg."
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="timed solves of each")
    args = parser.parse_args()
    print(format_table(*run(args.runs)))


if __name__ == "__main__":
    main()
