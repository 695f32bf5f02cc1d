"""Benchmark of the on-disk geometry cache (:mod:`attopt.experiments.environment.disk_cache`).

``python -m attopt.experiments.benchmarks.geometry [--runs 3] [--scenarios NAME ...]`` builds each
scenario's default geometry (:data:`SCENARIOS`) in a fresh Python process with an empty
cache directory, then again in another fresh process, which loads it, ``--runs`` times,
and prints the median, minimum and maximum of both times (imports excluded) and the
size of the entry.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path


def _wahba() -> Callable[[], object]:
    from attopt.experiments.wahba_mag_sun.experiment import WahbaMagSunParameters
    from attopt.experiments.wahba_mag_sun.scenario import build_geometry

    p = WahbaMagSunParameters()
    return lambda: build_geometry(p.orbit, p.start_utc, p.duration_s, p.step_s, p.attitude)


def _adsb() -> Callable[[], object]:
    from attopt.experiments.adsb_snr.scenario import build_adsb_geometry

    return build_adsb_geometry


def _geo() -> Callable[[], object]:
    from attopt.experiments.geo_snr_stations.scenario import build_geo_snr_scenario

    return lambda: build_geo_snr_scenario(manoeuvre=True)


def _doa() -> Callable[[], object]:
    from attopt.experiments.doa_ground.scenario import build_geometry

    return build_geometry


SCENARIOS: dict[str, Callable[[], Callable[[], object]]] = {
    "wahba-mag-sun": _wahba,
    "adsb-snr": _adsb,
    "geo-snr-stations": _geo,
    "doa-ground": _doa,
}
"""Scenario -> function that imports its builder and returns the default geometry's
zero-argument build."""


def time_build(scenario: str) -> float:
    """Seconds of one build of ``scenario``'s default geometry in this process (after its
    imports)."""
    build = SCENARIOS[scenario]()
    began = time.perf_counter()
    build()
    return time.perf_counter() - began


def _fresh_process(scenario: str, cache: Path) -> float:
    """:func:`time_build` in a new Python process with ``cache`` as the cache directory."""
    completed = subprocess.run(
        [sys.executable, "-m", "attopt.experiments.benchmarks.geometry", "--time", scenario],
        env={**os.environ, "ATTOPT_CACHE_DIR": str(cache)},
        capture_output=True,
        text=True,
        check=True,
    )
    return float(completed.stdout.split()[-1])


def run(scenarios: list[str], runs: int) -> list[dict[str, object]]:
    """Cold (empty cache) and warm (cached) build times of each scenario, ``runs`` times."""
    rows = []
    for scenario in scenarios:
        cold, warm, size = [], [], 0
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as directory:
                cache = Path(directory)
                cold.append(_fresh_process(scenario, cache))
                warm.append(_fresh_process(scenario, cache))
                size = sum(path.stat().st_size for path in cache.glob("*.npz"))
        rows.append({"scenario": scenario, "cold": cold, "warm": warm, "size_mb": size / 1e6})
    return rows


def format_table(rows: list[dict[str, object]]) -> str:
    """Markdown table of :func:`run`'s rows (median, min-max of each time)."""

    def spread(times: list[float]) -> str:
        return f"{statistics.median(times):.3f} ({min(times):.3f}-{max(times):.3f})"

    lines = [
        "| scenario | first build s, median (min-max) | cached s, median (min-max) | entry MB |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {r['scenario']} | {spread(r['cold'])} | {spread(r['warm'])} | {r['size_mb']:.2f} |"
        for r in rows
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--time", choices=SCENARIOS, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.time:
        print(time_build(args.time))
        return
    print(format_table(run(args.scenarios, args.runs)))


if __name__ == "__main__":
    main()
