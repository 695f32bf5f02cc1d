"""Arithmetic and table of the engine-overhead benchmark."""

from __future__ import annotations

import pytest

from attopt.experiments.benchmarks.runner import BenchRow, format_table, serial_loop


def test_overheads_are_worker_time_beyond_the_serial_loop():
    row = BenchRow("no-op", "local", 2, trials=10, wall_s=3.0, serial_s=5.0, startup_s=0.4)
    assert row.per_trial_ms == pytest.approx(300.0)
    assert row.overhead_ms == pytest.approx(1e3 * (6.0 - 5.0) / 10)
    assert row.steady_overhead_ms == pytest.approx(1e3 * (2 * 2.6 - 5.0) / 10)
    assert row.ratio == pytest.approx(0.6)
    serial = BenchRow("no-op", "serial loop", 1, trials=10, wall_s=5.0, serial_s=5.0, startup_s=0)
    table = format_table([serial, row])
    assert "| no-op | local | 2 | 10 | 3.00 | 0.6 | 300 | 100 |" in table
    assert "| local | 2 | 0.40 | 20 |" in table
    assert "| serial loop | 1 | 0.00" not in table


def test_serial_loop_times_the_trials():
    assert serial_loop({"settings": 2, "sleep_s": 0.01}, trials=2) >= 0.04
