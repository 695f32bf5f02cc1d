"""Benchmark of the filters' compiled loops (:mod:`attopt.solvers.filters.compiled`,
:mod:`attopt.formulations.geodesic`, :mod:`attopt.solvers.filters.vector_update`).

``python -m attopt.experiments.benchmarks.propagation [--runs 5] [--steps 10] [--calls
2000]`` times each loop two ways in the same process and run: the numpy reference
(:func:`~attopt.solvers.filters.common.covariance_steps`,
:func:`~attopt.solvers.filters.common.quaternion_steps`,
:func:`~attopt.solvers.filters.usque.unscented_prediction`,
:func:`~attopt.solvers.filters.common.block_nis_reference`,
:func:`~attopt.formulations.geodesic.geodesic_reference`,
:func:`~attopt.solvers.filters.mekf.update_reference`,
:func:`~attopt.solvers.filters.usque.update_reference`) and the compiled loop.  Six
cases: one prediction between two epochs (``--steps`` gyro steps of 0.1 s at a few
deg/s), the MEKF's (the covariance and one attitude) and USQUE's whole prediction (the
13 sigma attitudes, their mean and covariance, the process noise over the steps from a
zero covariance); two pieces of every update with a Sun and a magnetometer vector,
the gate's normalised innovations of the two vectors (MEKF: ``F = H^T``, ``W = P``) and
the unit vectors' innovation at USQUE's 13 sigma points; and the MEKF's and USQUE's whole
updates with those two vectors, given in the orbit frame as ``wahba-mag-sun`` gives them
(the attitude, bias and covariance compared).  It prints the median,
minimum and maximum over ``--runs`` of the mean time per prediction (``--calls`` calls
each), the ratio of the medians, and the largest difference between the two paths'
outputs.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from types import ModuleType

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import ReferencedMeasurement, VectorMeasurement
from attopt.formulations.geodesic import geodesic_reference, geodesic_rows
from attopt.formulations.gyro import MEMS_GYRO
from attopt.solvers.blocks import block_structure
from attopt.solvers.filters import common, compiled, mekf, update_kernels, usque


def _inputs(steps: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    dt = np.full(steps, 0.1)
    measured = rng.normal(size=(2, 3))
    measured /= np.linalg.norm(measured, axis=1, keepdims=True)
    a = rng.normal(size=(6, 6))
    return {
        "rates": np.radians([1.0, -2.0, 0.5]) + 1e-3 * rng.normal(size=(steps, 3)),
        "dt": dt,
        "covariance": 1e-4 * (a @ a.T + np.eye(6)),
        "noise": common.step_noise(MEMS_GYRO, dt, np.zeros(steps)),
        "attitude": Rotation.random(rng=rng).as_quat()[None],
        "bias": 1e-4 * rng.normal(size=3),
        "innovation": 1e-3 * rng.normal(size=6),
        "jacobian": rng.normal(size=(6, 6)),
        "variances": np.full(6, 1e-6),
        "measured": measured.ravel(),
        "sigma_predictions": (measured + 0.02 * rng.normal(size=(13, 2, 3))).reshape(13, 6),
    }


def _cases(x: dict[str, np.ndarray]) -> dict[str, dict[str, Callable[[], tuple]]]:
    """Per case, the numpy and compiled loops (the same arguments)."""
    offsets, _ = usque.sigma_offsets(x["covariance"])
    usque_arguments = (offsets, x["attitude"][0], x["bias"], x["rates"], x["dt"], x["noise"])

    def prediction(covariance_steps: Callable, quaternion_steps: Callable) -> Callable[[], tuple]:
        return lambda: (
            *covariance_steps(x["covariance"], x["rates"], x["dt"], x["noise"]),
            quaternion_steps(x["attitude"], x["rates"][None], x["dt"]),
        )

    paths = {
        "numpy": (common.covariance_steps, common.quaternion_steps),
        "compiled": (compiled.covariance_steps, compiled.quaternion_steps),
    }
    usque_paths = {"numpy": usque.unscented_prediction, "compiled": compiled.unscented_prediction}
    blocks = np.repeat([0, 1], 3)
    gate_arguments = (x["innovation"], x["jacobian"].T, x["covariance"], x["variances"])
    gate_paths = {
        "numpy": lambda: common.block_nis_reference(*gate_arguments, blocks),
        "compiled": lambda: update_kernels.block_nis(
            *gate_arguments, block_structure(blocks).members.members
        ),
    }
    vector_paths = {"numpy": geodesic_reference, "compiled": geodesic_rows}
    return {
        "MEKF prediction": {name: prediction(*f) for name, f in paths.items()},
        "USQUE prediction": {
            name: (lambda f=f: f(*usque_arguments)) for name, f in usque_paths.items()
        },
        "gate, two vectors": {name: (lambda f=f: f()) for name, f in gate_paths.items()},
        "vector innovation, 13 sigma points": {
            name: (lambda f=f: (f(x["sigma_predictions"], x["measured"]),))
            for name, f in vector_paths.items()
        },
        "MEKF update, two vectors": _updates(x, mekf),
        "USQUE update, two vectors": _updates(x, usque),
    }


def _updates(x: dict[str, np.ndarray], module: ModuleType) -> dict[str, Callable[[], tuple]]:
    """The update of ``module`` (:mod:`~attopt.solvers.filters.mekf` or
    :mod:`~attopt.solvers.filters.usque`) of a Sun and a magnetometer vector in the orbit
    frame, near the truth: its numpy path and its compiled call."""
    rng = np.random.default_rng(1)
    frame, truth = Rotation.random(rng=rng), Rotation.from_quat(x["attitude"][0])
    reference = x["measured"].reshape(2, 3)
    body = (truth * frame.inv()).apply(reference) + 1e-3 * rng.normal(size=(2, 3))
    measurement = ReferencedMeasurement(VectorMeasurement(body, reference, 1e-3), frame)
    estimate = Rotation.from_rotvec(1e-3 * rng.normal(size=3)) * truth
    arguments = (estimate, x["bias"], 1e-6 * np.eye(6), measurement, common.FilterOptions())

    def update(path: Callable) -> Callable[[], tuple]:
        def call() -> tuple:
            attitude, bias, covariance, _, _ = path(*arguments)
            return attitude.as_quat(), bias, covariance

        return call

    return {"numpy": update(module.update_reference), "compiled": update(module.update)}


def _time(call: Callable[[], tuple], runs: int, calls: int) -> list[float]:
    call()  # compile or load, warm up
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        for _ in range(calls):
            call()
        times.append((time.perf_counter() - start) / calls * 1e6)
    return times


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--calls", type=int, default=2000)
    args = parser.parse_args(argv)
    print(f"{args.steps} gyro steps per prediction; us per call, median (min-max)")
    print("| case | numpy | compiled | numpy / compiled | largest difference |")
    print("|---|---|---|---|---|")
    for case, paths in _cases(_inputs(args.steps)).items():
        numpy_times = _time(paths["numpy"], args.runs, args.calls)
        compiled_times = _time(paths["compiled"], args.runs, args.calls)
        difference = max(
            float(np.max(np.abs(a - b), initial=0.0))
            for a, b in zip(paths["numpy"](), paths["compiled"](), strict=True)
        )
        cells = [
            f"{statistics.median(t):.1f} ({min(t):.1f}-{max(t):.1f})"
            for t in (numpy_times, compiled_times)
        ]
        ratio = statistics.median(numpy_times) / statistics.median(compiled_times)
        print(f"| {case} | {cells[0]} | {cells[1]} | {ratio:.1f}x | {difference:.1e} |")


if __name__ == "__main__":
    main()
