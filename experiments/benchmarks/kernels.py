"""Benchmark of the measurement kernels (:mod:`attopt.formulations.kernels`).

``python -m attopt.experiments.benchmarks.kernels [--runs 5]`` evaluates each model
(:data:`CASES`: the ADS-B SNR of one observation, plain and threshold-truncated, as the
filters and the smoother evaluate it; three unit vectors; two DOA stations; the MUSIC
spectrum of the 12-element array) with its Jacobian at ``N`` points three ways, in
the same process and run:

* ``matrices``: the previous path, CasADi's interpreter on the map of ``N`` points
  called with CasADi matrices (the points side by side) and converted back with
  ``full()``;
* ``interpreted``: :func:`~attopt.formulations.kernels.evaluate_mapped` on numpy
  buffers with ``ATTOPT_KERNELS=interpreted``;
* ``compiled``: the same with the compiled kernel (the default).

It prints the median, minimum and maximum over ``--runs`` of the time per point, the
ratios of the medians to ``matrices``, the largest difference between the compiled and
interpreted outputs relative to the largest output (NaN, for the inputs outside a
pattern's main lobe, must be NaN in both), and each kernel's first-use cost (generation
and compilation into an empty cache directory).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations import kernels
from attopt.formulations.attitude_measurement import body_vectors_model
from attopt.formulations.attitude_model import attitude_model_function
from attopt.formulations.doa_array import YANG2014_UCA
from attopt.formulations.doa_measurement import doa_model
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.snr_measurement import truncated_mean_model
from attopt.formulations.snr_model import pattern_snr_model
from attopt.solvers.doa.music import spectrum_function

Inputs = Callable[[np.random.Generator, int], list[np.ndarray]]
HOUR_OF_SNRS = 1_143_873
"""Received SNRs of the hour of ``adsb-snr`` (``docs/benchmarks.md``, smoother)."""
SNR_SHAPES = ((1, 3), (1, 3), (1, 1), (1, 1))


def _attitudes(rng: np.random.Generator, n: int) -> np.ndarray:
    return Rotation.random(n, random_state=rng).as_matrix()


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _snr_inputs(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    a = _attitudes(rng, n)
    boresight = np.array([0.0, 0.0, 1.0])
    body = _unit(boresight + 0.4 * rng.normal(size=(n, 3)))  # inside the main lobe
    los = np.einsum("nji,nj->ni", a, body)  # A^T b: the orbit-frame line of sight
    return [a, los, np.tile(boresight, (n, 1)), np.full(n, 30.0), np.zeros(1)]


def _vector_inputs(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    return [_attitudes(rng, n), _unit(rng.normal(size=(3, 3)))]


def _doa_inputs(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    stations = np.array([[300.0, 100.0, 800.0], [-200.0, 400.0, 900.0]])
    return [_attitudes(rng, n), stations, np.zeros(3), np.eye(3)]


def _music_inputs(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    m = YANG2014_UCA.n_elements
    return [rng.uniform(0.0, np.pi, (n, 2)), rng.normal(size=(n, m)), rng.normal(size=(n, m))]


@dataclass(frozen=True)
class Case:
    name: str
    function: Callable[[], ca.Function]
    inputs: Inputs
    points: tuple[int, ...]


CASES = (
    Case(
        "SNR, one observation",
        lambda: attitude_model_function(pattern_snr_model(LIU2023_HELIX), SNR_SHAPES),
        _snr_inputs,
        (1, 300, HOUR_OF_SNRS),
    ),
    Case(
        "truncated SNR, one observation",
        lambda: attitude_model_function(truncated_mean_model(LIU2023_HELIX, 1.0, 6.0), SNR_SHAPES),
        _snr_inputs,
        (1, 300, HOUR_OF_SNRS),
    ),
    Case(
        "three unit vectors",
        lambda: attitude_model_function(body_vectors_model, ((3, 3),)),
        _vector_inputs,
        (1, 6000),
    ),
    Case(
        "two DOA stations",
        lambda: attitude_model_function(doa_model, ((2, 3), (3, 1), (3, 3))),
        _doa_inputs,
        (1, 6000),
    ),
    Case("MUSIC spectrum", lambda: spectrum_function(YANG2014_UCA), _music_inputs, (1, 1000)),
)


def evaluate_with_matrices(function: ca.Function, *inputs: np.ndarray) -> list[np.ndarray]:
    """The previous path: the interpreted map of ``N`` points on CasADi matrices."""
    n = max(x.reshape(-1, *function.size_in(i)).shape[0] for i, x in enumerate(inputs))
    arguments = []
    for i, x in enumerate(inputs):
        rows, columns = function.size_in(i)
        block = np.broadcast_to(x.reshape(-1, rows, columns), (n, rows, columns))
        arguments.append(ca.DM(block.transpose(1, 0, 2).reshape(rows, n * columns)))
    outputs = kernels._map(function, n)(*arguments)  # built once, as the previous path cached it
    outputs = outputs if isinstance(outputs, tuple) else (outputs,)
    return [
        o.full().reshape(function.size_out(i)[0], n, -1).transpose(1, 0, 2)
        for i, o in enumerate(outputs)
    ]


def _median_min_max(work: Callable[[], object], runs: int, n: int) -> tuple[float, float, float]:
    """Microseconds per point: median, minimum and maximum over ``runs`` (after one warm-up)."""
    work()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        work()
        times.append((time.perf_counter() - start) / n * 1e6)
    return statistics.median(times), min(times), max(times)


def _interpreted(work: Callable[[], object]) -> Callable[[], object]:
    def run() -> object:
        os.environ[kernels.KERNELS_ENV] = kernels.INTERPRETED
        try:
            return work()
        finally:
            del os.environ[kernels.KERNELS_ENV]

    return run


def first_use_seconds(function: ca.Function) -> float:
    """Generation and compilation of ``function`` into an empty cache directory."""
    saved = os.environ.get("ATTOPT_CACHE_DIR")
    with tempfile.TemporaryDirectory() as directory:
        os.environ["ATTOPT_CACHE_DIR"] = directory
        kernels._compiled.cache_clear()
        start = time.perf_counter()
        kernels.kernel(function)
        elapsed = time.perf_counter() - start
    if saved is None:
        del os.environ["ATTOPT_CACHE_DIR"]
    else:
        os.environ["ATTOPT_CACHE_DIR"] = saved
    kernels._compiled.cache_clear()
    return elapsed


def run(runs: int) -> list[dict[str, object]]:
    """One row per case and number of points (module docstring)."""
    if not kernels.compiled_kernels():
        raise SystemExit("no C compiler (or ATTOPT_KERNELS=interpreted): nothing to compare")
    rows = []
    for case in CASES:
        function = case.function()
        compile_s = first_use_seconds(function)
        for n in case.points:
            rows.append(_row(case, function, n, runs, compile_s))
    return rows


def _row(
    case: Case, function: ca.Function, n: int, runs: int, compile_s: float
) -> dict[str, object]:
    inputs = case.inputs(np.random.default_rng(n), n)

    def compiled() -> list[np.ndarray]:
        return kernels.evaluate_mapped(function, *inputs)

    def matrices() -> list[np.ndarray]:
        return evaluate_with_matrices(function, *inputs)

    interpreted = _interpreted(compiled)
    difference = 0.0
    for a, b in zip(compiled(), interpreted(), strict=True):
        if not np.array_equal(np.isnan(a), np.isnan(b)):
            difference = np.inf  # NaN in one path only
        scale = max(float(np.nanmax(np.abs(b), initial=0.0)), 1.0)
        difference = max(difference, float(np.nanmax(np.abs(a - b), initial=0.0)) / scale)
    return {
        "case": case.name,
        "points": n,
        "instructions": function.n_instructions(),
        "compile_s": compile_s,
        "difference": difference,
        "matrices": _median_min_max(matrices, runs, n),
        "interpreted": _median_min_max(interpreted, runs, n),
        "compiled": _median_min_max(compiled, runs, n),
    }


def format_table(rows: list[dict[str, object]], runs: int) -> str:
    def cell(t: tuple[float, float, float]) -> str:
        return f"{t[0]:.3g} ({t[1]:.3g}-{t[2]:.3g})"

    lines = [
        f"Measurement kernels: us per point, median (min-max) of {runs} runs; ratios of the "
        "medians to the previous path (CasADi matrices).",
        "",
        "| model | points | matrices | interpreted | compiled | matrices / interpreted "
        "| matrices / compiled | largest relative difference | first use s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m, i, c = r["matrices"][0], r["interpreted"][0], r["compiled"][0]
        lines.append(
            f"| {r['case']} | {r['points']:,} | {cell(r['matrices'])} | {cell(r['interpreted'])} "
            f"| {cell(r['compiled'])} | {m / i:.2f} | {m / c:.2f} | {r['difference']:.1e} "
            f"| {r['compile_s']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args(argv)
    print(format_table(run(args.runs), args.runs))


if __name__ == "__main__":
    main()
