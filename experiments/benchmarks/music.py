"""Benchmark of MUSIC with peak refinement against the CRB and pyroomacoustics.

``python -m attopt.experiments.benchmarks.music [--trials 200] [--seed 0]`` prints, in one
run:

* DOA RMSE of theta and phi against the stochastic CRB
  (:func:`attopt.formulations.doa_crb.stochastic_crb`) at input SNR -14..14 dB with
  L = 100 (Yang et al. 2014 Table 1) and at L = 1..1000 with SNR 0 dB (Table 2),
  with the paper's DOA RMSEs beside them.  Every trial has its own generator
  ``SeedSequence(seed, spawn_key=(condition, trial))``; the source is at
  ``theta = 45 deg``, ``phi = 60 deg`` (one CRB per condition).  RMSEs are
  over the accepted estimates; the rejected fraction (ambiguous peak) is
  shown.  ``L = 1`` uses the known SNR for its covariance.
* Cost per DOA estimate: batched (all trials of a condition in one call, per
  set) and one set per call, with two references measured in the same run:
  one ``numpy.linalg.eigh`` of a 12 x 12 complex covariance and one
  pyroomacoustics MUSIC call (1-degree grid over the same 70-degree cone).
* Cost of one ``doa-ground`` pass (``--pass-sets``, default 20000 sets, about
  one 5000-s pass) at SNR 0 dB (given), L = 100 and 1000, random directions
  in the paper's 62-degree cone: drawing the sample covariances directly
  (:func:`attopt.formulations.doa_array.simulate_sample_covariance`, Yang et al. 2014 eqs.
  8-10) and :meth:`MusicEstimator.estimate_covariance`, against simulating the
  snapshots and :meth:`MusicEstimator.estimate` in chunks of
  ``CHUNK_ELEMENTS`` samples (``experiments/doa_ground/experiment.py`` uses the direct
  draw); both measured in the same run, with their ratio.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pyroomacoustics as pra

from attopt.formulations.doa_array import (
    YANG2014_UCA,
    simulate_sample_covariance,
    simulate_snapshots,
)
from attopt.formulations.doa_crb import stochastic_crb
from attopt.solvers.doa import MusicEstimator

THETA, PHI = np.radians(45.0), np.radians(60.0)
SNR_SWEEP_DB = (-14.0, -12.0, -10.0, -8.0, -6.0, -2.0, 0.0, 14.0)
SNAPSHOT_SWEEP = (1, 10, 20, 50, 100, 1000)
CHUNK_ELEMENTS = 1 << 22
"""Complex snapshot samples simulated and estimated at once in the pass timing (64 MB)."""
YANG2014_TABLE1 = {  # SNR dB -> RMSE of theta, phi (deg), L = 100
    -14.0: (11.118, 68.128),
    -12.0: (4.106, 17.337),
    -10.0: (1.518, 1.307),
    -8.0: (0.921, 0.791),
    -6.0: (0.595, 0.534),
    -2.0: (0.354, 0.334),
    0.0: (0.315, 0.308),
    14.0: (0.287, 0.289),
}
YANG2014_TABLE2 = {  # L -> RMSE of theta, phi (deg), SNR 0 dB
    1: (8.354, 51.089),
    10: (0.781, 0.684),
    20: (0.408, 0.385),
    50: (0.342, 0.326),
    100: (0.315, 0.308),
    1000: (0.287, 0.289),
}


@dataclass(frozen=True)
class AccuracyRow:
    snr_db: float
    n_snapshots: int
    accepted: float
    rmse_deg: tuple[float, float]
    crb_deg: tuple[float, float]
    yang2014_deg: tuple[float, float]
    batch_ms: float


def _snapshots(snr_db: float, n_snapshots: int, trials: int, seed: int, condition: int):
    sets = [
        simulate_snapshots(
            THETA,
            PHI,
            snr_db,
            n_snapshots,
            np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(condition, trial))),
        )
        for trial in range(trials)
    ]
    return np.stack(sets)


def accuracy(
    estimator: MusicEstimator,
    snr_db: float,
    n_snapshots: int,
    trials: int,
    seed: int,
    condition: int,
) -> AccuracyRow:
    """RMSE, CRB and batched cost of one condition."""
    x = _snapshots(snr_db, n_snapshots, trials, seed, condition)
    known = snr_db if n_snapshots == 1 else None
    start = time.perf_counter()
    result = estimator.estimate(x, snr_db=known)
    batch_ms = (time.perf_counter() - start) / trials * 1e3
    ok = result.valid
    errors = np.column_stack(
        [result.theta[ok] - THETA, np.angle(np.exp(1j * (result.phi[ok] - PHI)))]
    )
    rmse = np.degrees(np.sqrt(np.mean(errors**2, axis=0))) if ok.any() else np.full(2, np.nan)
    crb = np.degrees(np.sqrt(np.diag(stochastic_crb(THETA, PHI, 10 ** (snr_db / 10), n_snapshots))))
    yang2014 = YANG2014_TABLE1[snr_db] if n_snapshots == 100 else YANG2014_TABLE2[n_snapshots]
    return AccuracyRow(
        snr_db, n_snapshots, float(ok.mean()), tuple(rmse), tuple(crb), yang2014, batch_ms
    )


def _median_seconds(call: Callable[[], object], repeats: int) -> float:
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def single_call_costs(estimator: MusicEstimator, seed: int) -> dict[str, float]:
    """Milliseconds per call: MUSIC on one set, one eigh, one pyroomacoustics MUSIC."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(99,)))
    x = simulate_snapshots(THETA, PHI, 0.0, 100, rng)
    covariance = x @ x.conj().T / x.shape[1]
    array = YANG2014_UCA
    c = 299792458.0
    reference = pra.doa.algorithms["MUSIC"](
        (array.radius_m * array.element_directions).T,
        2.0 * c / array.wavelength_m,
        2,
        c=c,
        num_src=1,
        dim=3,
        azimuth=np.radians(np.arange(0.0, 360.0, 1.0)),
        colatitude=np.radians(np.arange(0.5, np.degrees(estimator.cone_half_angle), 1.0)),
    )
    stft = np.zeros((array.n_elements, 2, x.shape[1]), dtype=complex)
    stft[:, 1, :] = x
    return {
        "MUSIC, one set per call": _median_seconds(lambda: estimator.estimate(x), 50) * 1e3,
        "numpy eigh of R (reference)": _median_seconds(lambda: np.linalg.eigh(covariance), 200)
        * 1e3,
        "pyroomacoustics MUSIC, 1-deg grid (reference)": _median_seconds(
            lambda: reference.locate_sources(stft, freq_bins=[1]), 10
        )
        * 1e3,
    }


def pass_costs(estimator: MusicEstimator, sets: int, seed: int) -> list[str]:
    """Table of the seconds per ``doa-ground`` pass of ``sets`` sets: covariance draw
    and snapshot draw (module docstring)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(98,)))
    theta = np.arccos(rng.uniform(np.cos(np.radians(62.0)), 1.0, sets))
    phi = rng.uniform(0.0, 2.0 * np.pi, sets)
    snr_db = 0.0

    def covariance_path(n_snapshots: int) -> None:
        drawn = simulate_sample_covariance(theta, phi, snr_db, n_snapshots, rng)
        estimator.estimate_covariance(drawn, n_snapshots, snr_db=snr_db)

    def snapshot_path(n_snapshots: int) -> None:
        chunk = max(1, CHUNK_ELEMENTS // (YANG2014_UCA.n_elements * n_snapshots))
        for start in range(0, sets, chunk):
            rows = slice(start, start + chunk)
            x = simulate_snapshots(theta[rows], phi[rows], snr_db, n_snapshots, rng)
            estimator.estimate(x, snr_db=snr_db)

    lines = [
        f"| L | covariance draw + MUSIC (s per {sets} sets) | snapshots + MUSIC (s) | ratio |",
        "|---|---|---|---|",
    ]
    for n_snapshots in (100, 1000):
        seconds = []
        for path in (covariance_path, snapshot_path):
            start = time.perf_counter()
            path(n_snapshots)
            seconds.append(time.perf_counter() - start)
        lines.append(
            f"| {n_snapshots} | {seconds[0]:.2f} | {seconds[1]:.2f} | "
            f"{seconds[1] / seconds[0]:.1f} |"
        )
    return lines


def format_rows(rows: list[AccuracyRow]) -> list[str]:
    lines = [
        "| SNR dB | L | accepted | RMSE theta / CRB (deg) | ratio | RMSE phi / CRB (deg) | ratio "
        "| Yang et al. 2014 theta, phi (deg) | batched ms/estimate |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratios = [r.rmse_deg[i] / r.crb_deg[i] for i in range(2)]
        lines.append(
            f"| {r.snr_db:g} | {r.n_snapshots} | {r.accepted:.3f} | "
            f"{r.rmse_deg[0]:.4f} / {r.crb_deg[0]:.4f} | {ratios[0]:.2f} | "
            f"{r.rmse_deg[1]:.4f} / {r.crb_deg[1]:.4f} | {ratios[1]:.2f} | "
            f"{r.yang2014_deg[0]}, {r.yang2014_deg[1]} | {r.batch_ms:.3f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pass-sets", type=int, default=20000)
    args = parser.parse_args()
    estimator = MusicEstimator()
    estimator.estimate(_snapshots(0.0, 100, 2, args.seed, 999))  # build the grid and functions
    conditions = [(snr, 100) for snr in SNR_SWEEP_DB] + [
        (0.0, n) for n in SNAPSHOT_SWEEP if n != 100
    ]
    rows = [
        accuracy(estimator, snr, n, args.trials, args.seed, i)
        for i, (snr, n) in enumerate(conditions)
    ]
    print(f"MUSIC vs CRB, theta = 45 deg, phi = 60 deg, {args.trials} trials per row")
    print("\n".join(format_rows(rows)))
    print()
    for name, ms in single_call_costs(estimator, args.seed).items():
        print(f"{name}: {ms:.3f} ms")
    print()
    print(f"One doa-ground pass: {args.pass_sets} sets at SNR 0 dB (given)")
    print("\n".join(pass_costs(estimator, args.pass_sets, args.seed)))


if __name__ == "__main__":
    main()
