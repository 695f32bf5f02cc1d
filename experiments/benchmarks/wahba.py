"""Benchmark of the Wahba solvers against ``scipy`` ``Rotation.align_vectors``.

Measured in one run on the same problems (two vectors, Sun + magnetometer
weights of Cilden Guler et al. 2017): per-call microseconds of every solver's single-epoch
``solve_vectors``, and batched solutions per second over ``n_batch`` epochs for the
vectorised solvers, each printed as a ratio to ``align_vectors`` called once
per epoch.  Batched answers are checked against ``align_vectors`` (they must
agree to 1e-9 rad).  The SDP is timed per solve after its first (compiling)
solve.  Each compiled method (:mod:`attopt.solvers.wahba.compiled`) is measured beside
its numpy reference in the same run (rows "name (numpy)"); times are the median, minimum
and maximum over 5 repeats (per call) and 3 (batched).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error
from attopt.solvers.registry import ESTIMATORS
from attopt.solvers.wahba import NUMPY_REFERENCES, SDP, WahbaSolver
from attopt.solvers.wahba.sdp import SdpOptions


@dataclass(frozen=True)
class BenchRow:
    """One solver's times: per call (us) and batched (epochs/s), each the median, minimum
    and maximum over the repeats, with the ratios of the medians to ``align_vectors``."""

    method: str
    per_call_us: float
    per_call_min_us: float
    per_call_max_us: float
    per_call_ratio: float
    batch_per_s: float
    batch_min_per_s: float
    batch_max_per_s: float
    batch_ratio: float
    max_diff_rad: float


def _problems(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, Rotation]:
    rng = np.random.default_rng(seed)
    truth = Rotation.random(n, random_state=rng)
    reference = rng.normal(size=(n, 2, 3))
    reference /= np.linalg.norm(reference, axis=-1, keepdims=True)
    sigma = np.array([0.002, 0.008])
    body = np.stack([truth.apply(reference[:, i]) for i in range(2)], axis=1)
    body += sigma[:, None] * rng.normal(size=body.shape)
    body /= np.linalg.norm(body, axis=-1, keepdims=True)
    return body, reference, np.tile(sigma**-2, (n, 1)), truth


def _per_call_seconds(call: Callable[[int], object], calls: int) -> np.ndarray:
    """The mean time of ``calls`` calls, in each of 5 repeats."""
    call(0)
    times = []
    for _ in range(5):
        start = time.perf_counter()
        for i in range(calls):
            call(i)
        times.append((time.perf_counter() - start) / calls)
    return np.array(times)


REFERENCES = {"sdp, one solve per epoch": replace(SDP, options=SdpOptions(block_size=1))}
"""Previous algorithms kept as options, measured in the same run as their references."""


def benchmarked() -> list[tuple[str, WahbaSolver]]:
    """Every registered Wahba solver, the numpy reference of each compiled one
    (:meth:`~attopt.solvers.wahba.WahbaSolver.numpy_reference`), and :data:`REFERENCES`."""
    registered = [e for e in ESTIMATORS.values() if isinstance(e, WahbaSolver)]
    return [(s.label, s) for s in [*registered, *NUMPY_REFERENCES]] + list(REFERENCES.items())


def run(n_batch: int = 100_000, calls: int = 2000, seed: int = 0) -> list[BenchRow]:
    """Measure every solver of :func:`benchmarked` and the ``align_vectors`` reference."""
    body, reference, weights, _ = _problems(max(n_batch, calls), seed)

    def align(i: int) -> Rotation:
        return Rotation.align_vectors(body[i], reference[i], weights[i])[0]

    ref_calls = _per_call_seconds(align, calls)
    ref_call = float(np.median(ref_calls))
    ref_throughput = 1.0 / ref_call
    check = min(n_batch, 5000)
    reference_att = Rotation.concatenate([align(i) for i in range(check)])
    rows = [
        BenchRow(
            "align_vectors (scipy)",
            ref_call * 1e6,
            ref_calls.min() * 1e6,
            ref_calls.max() * 1e6,
            1.0,
            ref_throughput,
            1.0 / ref_calls.max(),
            1.0 / ref_calls.min(),
            1.0,
            0.0,
        )
    ]
    for label, solver in benchmarked():
        n_calls = calls if solver.vectorised else max(calls // 10, 20)
        per_call = _per_call_seconds(
            lambda i, s=solver: s.solve_vectors(body[i], reference[i], weights[i]), n_calls
        )
        n = n_batch if solver.vectorised else min(n_batch, 500)
        solver.solve_batch(body[:2], reference[:2], weights[:2])
        elapsed = []
        for _ in range(3):
            start = time.perf_counter()
            batch = solver.solve_batch(body[:n], reference[:n], weights[:n])
            elapsed.append(time.perf_counter() - start)
        throughput = n / np.array(elapsed)
        m = min(n, check)
        est = Rotation.from_quat(batch.quaternion[:m])
        diff = float(np.abs(np.linalg.norm(attitude_error(est, reference_att[:m]), axis=1)).max())
        rows.append(
            BenchRow(
                label,
                float(np.median(per_call)) * 1e6,
                per_call.min() * 1e6,
                per_call.max() * 1e6,
                ref_call / float(np.median(per_call)),
                float(np.median(throughput)),
                throughput.min(),
                throughput.max(),
                float(np.median(throughput)) / ref_throughput,
                diff,
            )
        )
    return rows


def format_table(rows: list[BenchRow], n_batch: int) -> str:
    """Markdown table of the measurements: medians with (min-max)."""
    lines = [
        "| method | per call (us) | per-call speed vs align_vectors | batched epochs/s "
        f"(N = {n_batch:,}; SDP 500) | batched vs align_vectors per call | max diff vs "
        "align_vectors (rad) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.method} | {r.per_call_us:.1f} ({r.per_call_min_us:.1f}-{r.per_call_max_us:.1f})"
            f" | {r.per_call_ratio:.2f}x | {r.batch_per_s:,.0f} ({r.batch_min_per_s:,.0f}-"
            f"{r.batch_max_per_s:,.0f}) | {r.batch_ratio:.1f}x | {r.max_diff_rad:.1e} |"
        )
    return "\n".join(lines)
