"""Benchmark of the SNR attitude solvers (Liu et al. 2023 secs. 3.2-3.3) at 20 observations.

Epochs come from the ``adsb-snr`` scenario (:mod:`attopt.experiments.adsb_snr.scenario`):
real satellite-to-aircraft geometry, true attitude wandering by a few degrees,
SNR from the seed-000 helix (eq. 63) and the link budget plus 1 dB Gaussian
noise (sec. 5.1).  Messages below the 6 dB threshold are not received; of
the rest, 20 per epoch are kept, up to 10 per antenna (at least 3 each).
Epochs are solved in order, one ``solve`` call per epoch, warm-started from
the previous epoch's estimate where the variant says so, and each call is
timed (validation, solve, covariance and result assembly included).  The
table gives the median milliseconds per epoch, the ratio to the NLSE
(warm-started) measured in the same run, median iterations (IPOPT
iterations, MINPACK residual evaluations, QUEST Newton steps), failed epochs,
and the RMS attitude error.  A second table (:func:`solver_floor`) times the two
``nlpsol`` plugins alone on a 3-variable quadratic: the cost of IPOPT itself; a third
(:func:`truncated_derivatives`) the truncated likelihood's NLP on whole ``adsb-snr``
epochs with CasADi's own derivatives and with the compiled ones.  Run with
``python -m attopt.experiments.benchmarks.snr``.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.parameters import AdsbScenario
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry, observation_table
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import AttoptError
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.link_budget import LinkBudget
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import SNR_SIGMA_DB, predict_snr
from attopt.formulations.snr_problem import RECEPTION_THRESHOLD_DB, SnrEpoch
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.registry import estimator
from attopt.solvers.results import Solution
from attopt.solvers.snr.driver import SnrSolver

OBSERVATIONS = 20
PER_ANTENNA = 10
MIN_PER_ANTENNA = 3


@dataclass(frozen=True)
class BenchRow:
    variant: str
    median_ms: float
    ratio_to_nlse: float
    median_iterations: float
    failures: int
    rms_error_deg: float
    spread_ms: tuple[float, float] = (np.nan, np.nan)
    """Smallest and largest of the repeats' medians."""


def _epochs(n_epochs: int, seed: int) -> tuple[list[SnrEpoch], Rotation]:
    """Scenario epochs with ``OBSERVATIONS`` received messages each, and their true attitudes."""
    geometry = build_adsb_geometry(AdsbScenario(duration_s=float(n_epochs)))
    table = observation_table(geometry, np.degrees(LIU2023_HELIX.max_off_boresight_rad))
    boresights = geometry.boresights_body
    rng = np.random.default_rng(seed)
    budget = LinkBudget()
    epochs, truths = [], []
    for k in range(n_epochs):
        rows = table.take(table.epoch_index == k)
        p0 = budget.isotropic_power_dbw(rows.range_m)
        truth = geometry.truth[k]
        snr, _ = predict_snr(
            truth,
            rows.los_orbit,
            boresights[rows.antenna],
            p0,
            budget.noise_power_dbw,
            LIU2023_HELIX,
        )
        snr = snr + SNR_SIGMA_DB * rng.normal(size=snr.shape)
        received = snr >= RECEPTION_THRESHOLD_DB
        pick = _pick(rng, rows.antenna, received)
        if pick is None:
            continue
        epochs.append(
            SnrEpoch.from_ranges(
                snr[pick],
                rows.los_orbit[pick],
                rows.antenna[pick],
                boresights,
                rows.range_m[pick],
                LIU2023_HELIX,
                budget,
            )
        )
        truths.append(truth)
    return epochs, Rotation.concatenate(truths)


def _pick(rng: np.random.Generator, antenna: np.ndarray, received: np.ndarray) -> np.ndarray | None:
    """``OBSERVATIONS`` received rows, up to ``PER_ANTENNA`` per antenna, or None."""
    by_antenna = [rng.permutation(np.flatnonzero(received & (antenna == a))) for a in (0, 1)]
    if min(len(rows) for rows in by_antenna) < MIN_PER_ANTENNA:
        return None
    first = [rows[:PER_ANTENNA] for rows in by_antenna]
    rest = np.concatenate([rows[PER_ANTENNA:] for rows in by_antenna])
    chosen = np.concatenate([*first, rest[: OBSERVATIONS - sum(len(f) for f in first)]])
    return np.sort(chosen) if chosen.size == OBSERVATIONS else None


def _measure(
    solver: SnrSolver, snapshots: list[Snapshot], warm: bool
) -> tuple[list[float], list[Solution | None]]:
    """Seconds per epoch and solutions, epochs in order (failures are None)."""
    seconds, solutions = [], []
    previous: Rotation | None = None
    for snapshot in snapshots:
        start = time.perf_counter()
        try:
            solution = solver.solve(snapshot, prior=previous if warm else None)
        except AttoptError:  # a flagged epoch is counted, not fatal
            solution = None
        seconds.append(time.perf_counter() - start)
        solutions.append(solution)
        if warm and solution is not None:
            previous = solution.attitude
    return seconds, solutions


def run(n_epochs: int = 300, seed: int = 0, repeats: int = 3) -> list[BenchRow]:
    """Measure every variant on the same epochs; print and return the table rows."""
    epochs, truths = _epochs(n_epochs, seed)
    snapshots = [Snapshot.of(SnrMeasurement(epoch)) for epoch in epochs]
    nlse, nlp, deterministic = (estimator(n) for n in ("nlse", "nlp", "deterministic"))
    lbfgs = estimator("nlp", options=NlpOptions(hessian_approximation="limited-memory"))
    sqp = estimator("nlp", options=NlpOptions(solver="sqpmethod"))
    variants: list[tuple[str, SnrSolver, bool]] = [
        ("nlse (warm start)", nlse, True),
        ("nlse (two-step start)", nlse, False),
        ("nlp, exact Hessian (warm start)", nlp, True),
        ("nlp, exact Hessian (two-step start)", nlp, False),
        ("nlp, L-BFGS (warm start)", lbfgs, True),
        ("nlp, SQP method (warm start)", sqp, True),
        ("nlp, SQP method (two-step start)", sqp, False),
        ("deterministic (two-step, QUEST)", deterministic, False),
    ]
    for _, solver, warm in variants:  # build every cached CasADi function before timing
        _measure(solver, snapshots[:2], warm)
    rows = []
    for name, solver, warm in variants:
        medians = []
        for _ in range(repeats):
            seconds, solutions = _measure(solver, snapshots, warm)
            medians.append(float(np.median(seconds)))
        row = _row(name, float(np.median(medians)), solutions, truths)
        rows.append(replace(row, spread_ms=(1e3 * min(medians), 1e3 * max(medians))))
    reference = rows[0].median_ms
    rows = [replace(r, ratio_to_nlse=r.median_ms / reference) for r in rows]
    print(f"{len(epochs)} epochs, {OBSERVATIONS} observations each")
    print(format_table(rows))
    return rows


def _row(
    name: str, median_s: float, solutions: list[Solution | None], truths: Rotation
) -> BenchRow:
    ok = [i for i, s in enumerate(solutions) if s is not None]
    errors = np.array([attitude_error(solutions[i].attitude, truths[i]) for i in ok])
    iterations = [
        solutions[i].diagnostics.get("iterations", solutions[i].diagnostics.get("quest_iterations"))
        for i in ok
    ]
    return BenchRow(
        name,
        median_s * 1e3,
        np.nan,
        float(np.median(iterations)),
        len(solutions) - len(ok),
        float(np.degrees(np.sqrt(np.mean(np.sum(errors**2, axis=1))))),
    )


def format_table(rows: list[BenchRow]) -> str:
    """Markdown table of the measurements."""
    lines = [
        "| solver | median ms/epoch (min-max of repeats) | vs nlse (warm) | median iterations | "
        "failures | RMS error (deg) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        low, high = r.spread_ms
        lines.append(
            f"| {r.variant} | {r.median_ms:.2f} ({low:.2f}-{high:.2f}) | "
            f"{r.ratio_to_nlse:.2f}x | {r.median_iterations:g} | {r.failures} | "
            f"{r.rms_error_deg:.2f} |"
        )
    return "\n".join(lines)


def solver_floor(calls: int = 300, repeats: int = 3) -> list[tuple[str, float, int]]:
    """Milliseconds per ``nlpsol`` call of each solver on a 3-variable quadratic
    ``|x - p|^2 + 0.1 |x|^4`` (no measurement model: the solvers' own cost), IPOPT
    stopped after 0 and 1 iterations and run to convergence, and the SQP method; the
    median of ``repeats`` runs of ``calls`` calls each, and the ratio to converged IPOPT
    measured in the same run.  Printed and returned as ``(variant, ms, iterations)``."""
    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 3)
    problem = {"x": x, "p": p, "f": ca.sumsqr(x - p) + 0.1 * ca.sumsqr(x) ** 2}
    variants = [
        ("IPOPT, stopped at the start", NlpOptions(max_iter=0)),
        ("IPOPT, stopped after 1 iteration", NlpOptions(max_iter=1)),
        ("IPOPT, converged", NlpOptions()),
        ("SQP method, converged", NlpOptions(solver="sqpmethod")),
    ]
    rows = []
    for name, options in variants:
        solver = ca.nlpsol("floor", options.solver, problem, options.nlpsol_options())
        runs = []
        for _ in range(repeats + 1):  # the first run warms up
            start = time.perf_counter()
            for _ in range(calls):
                solver(x0=np.zeros(3), p=[1.0, 2.0, 3.0])
            runs.append((time.perf_counter() - start) / calls)
        rows.append((name, 1e3 * float(np.median(runs[1:])), int(solver.stats()["iter_count"])))
    reference = rows[2][1]
    print("| solver on a 3-variable quadratic | ms per call | iterations | vs IPOPT converged |")
    print("|---|---|---|---|")
    for name, ms, iterations in rows:
        print(f"| {name} | {ms:.3f} | {iterations} | {ms / reference:.2f}x |")
    return rows


def truncated_derivatives(duration_s: float = 60.0, repeats: int = 3) -> list[tuple[str, float]]:
    """Milliseconds per IPOPT solve of the truncated likelihood (``nlp_truncated``'s NLP) on
    the received SNRs of the first ``duration_s`` epochs of ``adsb-snr`` (seed 0; about
    170 an epoch, padded to 256), started at the true attitude: with CasADi's own
    derivatives (``ATTOPT_KERNELS=interpreted``) and with the compiled ones
    (:mod:`attopt.solvers.snr.nlp_derivatives`), alternately, the median over the epochs
    of each of ``repeats`` runs; the ratio in the same run and the largest difference of
    the estimates.  Printed and returned as ``(variant, median ms)``."""
    from attopt.experiments.adsb_snr.experiment import AdsbSnrParameters, trial_pass
    from attopt.formulations import kernels
    from attopt.solvers.snr.nlp import solve_local

    scenario, noisy = trial_pass(
        AdsbSnrParameters(duration_s=duration_s), np.random.SeedSequence(0, spawn_key=(0, 0))
    )
    modes = {"CasADi's derivatives": kernels.INTERPRETED, "compiled derivatives": "compiled"}
    medians: dict[str, list[float]] = {name: [] for name in modes}
    estimates: dict[str, list[Rotation]] = {}
    previous = os.environ.get(kernels.KERNELS_ENV)
    try:
        for _ in range(repeats + 1):  # the first run builds (and compiles) and warms up
            for name, mode in modes.items():
                os.environ[kernels.KERNELS_ENV] = mode
                seconds, attitudes = [], []
                for k, epoch in enumerate(noisy.epochs):
                    start = time.perf_counter()
                    result = solve_local(epoch, scenario.truth[k], NlpOptions(), "truncated_ml")
                    seconds.append(time.perf_counter() - start)
                    attitudes.append(result.attitude)
                medians[name].append(1e3 * float(np.median(seconds)))
                estimates[name] = attitudes
    finally:
        if previous is None:
            os.environ.pop(kernels.KERNELS_ENV, None)
        else:
            os.environ[kernels.KERNELS_ENV] = previous
    rows = [(name, float(np.median(runs[1:]))) for name, runs in medians.items()]
    difference = max(
        float((a * b.inv()).magnitude()) for a, b in zip(*estimates.values(), strict=True)
    )
    print("| truncated-likelihood NLP, IPOPT | median ms per solve (runs) | vs CasADi's |")
    print("|---|---|---|")
    for name, ms in rows:
        runs = " / ".join(f"{m:.2f}" for m in medians[name][1:])
        print(f"| {name} | {ms:.2f} ({runs}) | {ms / rows[0][1]:.2f}x |")
    print(f"largest difference of the estimates: {difference:.1e} rad")
    return rows


if __name__ == "__main__":
    run()
    solver_floor()
    truncated_derivatives()
