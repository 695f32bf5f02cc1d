"""Scaling benchmark of the batch factor-graph smoother on ``adsb-snr``.

For each pass length (default 15 min, 1 h, 4 h) on the ``adsb-snr``
scenario (:mod:`attopt.experiments.adsb_snr.experiment`: Liu et al. 2023's noise and 6 dB
threshold, 10,000 aircraft, 1 s epochs), with the measurements the SNR filters use
(:func:`attopt.experiments.adsb_snr.filters.snr_measurements`, threshold-truncated
model, wrapped for the inertial attitude by
:func:`attopt.experiments.simulation.referenced`) and the ``mems`` gyro at 10 Hz
(:func:`attopt.experiments.simulation.simulate_filter_inputs`, 10 deg initial
attitude error), it times:

* ``mekf``: the forward MEKF (``mekf_snr``), and ``rts`` its backward pass;
* ``smoother``: the batch smoother (registry estimator ``fg_batch``,
  :class:`attopt.solvers.smoother.BatchSmoother`) started from the RTS result
  (``initial=``; the time of the smoother alone, split into the problem's set-up,
  optimisation and marginals, with the number of passes over the
  measurements, each one ``predict`` per epoch);
* ``predict``: one pass of ``predict`` over all epochs at the truth, the
  interface's cost that bounds the smoother's from below;
* ``online`` (with ``--online``): the online smoother (registry estimator
  ``fg_online``, :class:`attopt.solvers.smoother.OnlineSmoother`) with its
  default options (causal estimates, split into factor set-up and iSAM2
  updates with marginals, with its ratio to the MEKF of the same run, its
  model evaluations per epoch and its window).

and reports each method's RMS attitude error (body axes, degrees, all valid
epochs and those after 300 s), the posterior Cramer-Rao bound of the pass
(:func:`attopt.solvers.bounds.posterior_bound`, the smoother's marginal
covariance at the truth: its information is the
Fisher information of the whole pass, gyro and prior included; RMS over the
epochs of the square root of its trace), the same for the smoother's own
covariance at its solution (``sigma``) and its mean NEES, and the time ratio
per doubling of the pass (target: at most 2.5).  One trial: the errors of a
pass are strongly correlated in time, so its RMS can differ from the bound
by tens of per cent either way; the RMS-to-bound ratio needs Monte Carlo.

Run with ``python -m attopt.experiments.benchmarks.smoother`` (``--durations 900 1800
3600`` for other lengths; building the 4 h scenario takes about a minute;
``--online`` adds the online smoother).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from attopt.experiments.adsb_snr.experiment import noise_free_pass, power_offsets, simulate_pass
from attopt.experiments.adsb_snr.filters import adsb_gyro_truth, snr_measurements
from attopt.experiments.adsb_snr.parameters import AdsbScenario
from attopt.experiments.simulation import GyroPass, child_rng, simulate_filter_inputs
from attopt.formulations.conventions import attitude_error
from attopt.formulations.gyro import GYRO_MODELS
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.bounds import posterior_bound
from attopt.solvers.registry import estimator
from attopt.solvers.smoother import OnlineReport

BURN_IN_S = 300.0


@dataclass(frozen=True)
class Row:
    duration_s: float
    epochs: int
    observations: int
    build_s: float
    predict_s: float
    mekf_s: float
    rts_s: float
    smoother_s: float
    factors_s: float
    optimisation_s: float
    marginals_s: float
    evaluations: int
    iterations: int
    converged: bool
    rms_deg: dict[str, float]
    rms_late_deg: dict[str, float]
    bound_deg: float
    sigma_deg: float
    nees: float
    online_s: float | None = None
    online: OnlineReport | None = None


def _rms(solution, truth, late: np.ndarray) -> tuple[float, float]:
    valid = solution.valid
    error = np.full((valid.size, 3), np.nan)
    error[valid] = attitude_error(solution.attitude(), truth[valid])
    squared = np.sum(error**2, axis=1)
    return (
        float(np.degrees(np.sqrt(np.nanmean(squared)))),
        float(np.degrees(np.sqrt(np.nanmean(squared[late])))),
    )


@dataclass(frozen=True)
class BenchmarkPass:
    """A simulated ``adsb-snr`` pass for the benchmarks: the gyro-aided pass (ECI), the
    epochs' SNRs (orbit frame, for the single-frame methods) and the scenario's build time."""

    simulated: GyroPass
    epochs: list[SnrEpoch]
    build_s: float


def adsb_pass(
    duration_s: float, seed: int, gyro: str, offset_sigma_db: float = 0.0
) -> BenchmarkPass:
    """The scenario's pass of ``duration_s`` with seed ``seed``'s SNR noise (and its power
    offsets, ``offset_sigma_db`` per aircraft), the truncated SNR model and the ``gyro``
    preset at 10 Hz (module docstring)."""
    start = time.perf_counter()
    parameters = AdsbScenario(duration_s=duration_s)
    scenario = noise_free_pass(parameters)
    truth = adsb_gyro_truth(parameters, 10.0)
    build = time.perf_counter() - start
    root = np.random.SeedSequence(seed)
    noisy = simulate_pass(
        scenario,
        np.random.default_rng(root),
        parameters.receiver.snr_sigma_db,
        parameters.receiver.threshold_db,
        power_offsets(scenario, root, offset_sigma_db),
    )
    inputs = simulate_filter_inputs(truth, GYRO_MODELS[gyro], child_rng(root, 1))
    simulated = inputs.gyro_pass(truth, snr_measurements(noisy.epochs, "truncated"))
    return BenchmarkPass(simulated, noisy.epochs, build)


def run(duration_s: float, seed: int, gyro: str, online: bool = False) -> Row:
    """One pass of ``duration_s`` (module docstring)."""
    benchmark = adsb_pass(duration_s, seed, gyro)
    simulated, build = benchmark.simulated, benchmark.build_s
    pass_, true_attitude = simulated.pass_, simulated.attitude
    measurements = pass_.measurements()
    t = pass_.t
    late = t >= t[0] + BURN_IN_S

    start = time.perf_counter()
    for k, m in enumerate(measurements):
        if m is not None:
            m.predict(true_attitude[k])
    predict = time.perf_counter() - start

    start = time.perf_counter()
    forward = estimator("mekf").solve(pass_)
    mekf_s = time.perf_counter() - start
    start = time.perf_counter()
    backward = estimator("rts").solve(pass_, initial=forward)
    rts_s = time.perf_counter() - start
    start = time.perf_counter()
    result = estimator("fg_batch").solve(pass_, initial=backward)
    smoother_s = time.perf_counter() - start
    report = result.report

    trace = np.sum(posterior_bound(pass_, true_attitude, simulated.bias) ** 2, axis=1)

    solutions = {"mekf": forward, "rts": backward, "smoother": result}
    online_s = None
    if online:
        start = time.perf_counter()
        solutions["online"] = estimator("fg_online").solve(pass_)
        online_s = time.perf_counter() - start
    rms, rms_late = {}, {}
    for name, estimate in solutions.items():
        rms[name], rms_late[name] = _rms(estimate, true_attitude, late)
    valid = result.valid
    error = attitude_error(result.attitude(), true_attitude[valid])
    nees = np.einsum("ki,kij,kj->k", error, np.linalg.inv(result.covariance[valid]), error)
    return Row(
        duration_s=duration_s,
        epochs=t.size,
        observations=int(sum(m.size for m in measurements if m is not None)),
        build_s=build,
        predict_s=predict,
        mekf_s=mekf_s,
        rts_s=rts_s,
        smoother_s=smoother_s,
        factors_s=report.seconds["factors"],
        optimisation_s=report.seconds["optimisation"],
        marginals_s=report.seconds["marginals"],
        evaluations=report.evaluations,
        iterations=report.iterations,
        converged=report.converged,
        rms_deg=rms,
        rms_late_deg=rms_late,
        bound_deg=float(np.degrees(np.sqrt(np.nanmean(trace)))),
        sigma_deg=float(
            np.degrees(np.sqrt(np.nanmean(np.trace(result.covariance, axis1=1, axis2=2))))
        ),
        nees=float(np.mean(nees)),
        online_s=online_s,
        online=solutions["online"].report if online else None,
    )


def format_table(rows: list[Row], gyro: str) -> str:
    lines = [
        f"Batch smoother on adsb-snr (truncated SNR model, {gyro} gyro at 10 Hz), "
        "started from the RTS result; times in seconds.",
        "",
        "| pass | epochs | SNRs | smoother | factors / optimise / marginals | passes | "
        "per doubling | us per SNR | one predict pass | mekf | rts |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    previous = None
    for r in rows:
        doubling = ""
        if previous is not None:
            exponent = np.log2(r.duration_s / previous.duration_s)
            doubling = f"{(r.smoother_s / previous.smoother_s) ** (1.0 / exponent):.2f}"
        lines.append(
            f"| {r.duration_s / 60:.0f} min | {r.epochs} | {r.observations} | "
            f"{r.smoother_s:.1f} | {r.factors_s:.1f} / {r.optimisation_s:.1f} / "
            f"{r.marginals_s:.1f} | {r.evaluations + 1} ({r.iterations} it., "
            f"{'converged' if r.converged else 'NOT converged'}) | {doubling} | "
            f"{1e6 * r.smoother_s / r.observations:.1f} | "
            f"{r.predict_s:.1f} | {r.mekf_s:.1f} | {r.rts_s:.1f} |"
        )
        previous = r
    lines += [
        "",
        f"RMS attitude error (deg; all epochs, and after {BURN_IN_S:.0f} s) and the "
        "posterior bound (RMS of the marginal covariance at the truth):",
        "",
        "| pass | mekf | rts | smoother | bound | smoother / bound | smoother sigma | "
        "smoother NEES (3) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cells = " | ".join(
            f"{r.rms_deg[m]:.4f} / {r.rms_late_deg[m]:.4f}" for m in ("mekf", "rts", "smoother")
        )
        lines.append(
            f"| {r.duration_s / 60:.0f} min | {cells} | {r.bound_deg:.4f} | "
            f"{r.rms_deg['smoother'] / r.bound_deg:.3f} | {r.sigma_deg:.4f} | {r.nees:.2f} |"
        )
    if all(r.online is not None for r in rows):
        lines += ["", *format_online(rows)]
    return "\n".join(lines)


def format_online(rows: list[Row]) -> list[str]:
    """The online smoother's cost against the MEKF of the same run, and its RMS."""
    lag = rows[0].online.lag_s
    lines = [
        f"Online smoother (lag {lag:g} s, default options; causal estimates); times in "
        "seconds, ratios against the MEKF of the same run:",
        "",
        "| pass | online | factors / updates | per doubling | online / mekf | "
        "us per SNR | updates (extra) | predicts per epoch (reused) | window | "
        "RMS online / mekf (all; late) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    previous = None
    for r in rows:
        o = r.online
        doubling = ""
        if previous is not None:
            exponent = np.log2(r.duration_s / previous.duration_s)
            doubling = f"{(r.online_s / previous.online_s) ** (1.0 / exponent):.2f}"
        lines.append(
            f"| {r.duration_s / 60:.0f} min | {r.online_s:.1f} | {o.seconds['factors']:.1f} / "
            f"{o.seconds['update']:.1f} | {doubling} | "
            f"{r.online_s / r.mekf_s:.2f} | {1e6 * r.online_s / r.observations:.1f} | "
            f"{o.updates} ({o.extra_updates}) | {o.evaluations / r.epochs:.2f} "
            f"({o.reused / r.epochs:.2f}) | {o.max_window} | "
            f"{r.rms_deg['online']:.4f} / {r.rms_deg['mekf']:.4f}; "
            f"{r.rms_late_deg['online']:.4f} / {r.rms_late_deg['mekf']:.4f} |"
        )
        previous = r
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--durations", type=float, nargs="+", default=[900.0, 3600.0, 14400.0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gyro", default="mems", choices=sorted(GYRO_MODELS))
    parser.add_argument("--online", action="store_true", help="also time the online smoother")
    args = parser.parse_args()
    rows = []
    for duration in sorted(args.durations):
        rows.append(run(duration, args.seed, args.gyro, args.online))
        r = rows[-1]
        online = f", online {r.online_s:.1f} s" if args.online else ""
        print(
            f"{duration:.0f} s: smoother {r.smoother_s:.1f} s ({r.evaluations + 1} passes), "
            f"mekf {r.mekf_s:.1f} s{online}, build {r.build_s:.1f} s",
            flush=True,
        )
    print(format_table(rows, args.gyro))


if __name__ == "__main__":
    main()
