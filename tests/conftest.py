"""Test configuration.

* Hypothesis runs derandomised under CI so a CI run is reproducible.
* The on-disk geometry cache (``experiments/environment/disk_cache.py``) lives in the
  run's temporary directory, never in the user's cache (below).
* Under pytest-xdist the workers share the numba loops' compilation before the first
  test (below), as a sweep's workers do.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.hookimpl(trylast=True)  # after pytest's tmp_path plugin has set up its factory
def pytest_configure(config: pytest.Config) -> None:
    """Point ``ATTOPT_CACHE_DIR`` at ``attopt-cache`` in the run's base temporary directory.

    Set here, before collection, so that no test module builds a geometry into the user's
    cache.  A pytest-xdist worker's base directory is ``popen-gwN`` inside the run's (the
    controller's), so every worker uses the run's directory: the workers of one run share
    each geometry (the first to need it builds it, the others load it), and each run
    starts empty, so the suite also exercises building.  Tests of the cache itself set
    their own directory.
    """
    base = config._tmp_path_factory.getbasetemp()
    run = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    os.environ["ATTOPT_CACHE_DIR"] = str(run / "attopt-cache")


WARM_UP_WAIT_S = 900.0
"""How long a worker waits for the others' share of the numba loops before going on."""


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist, worker ``k`` of ``n`` compiles every ``n``-th numba loop
    (:func:`attopt.solvers.compilation.loop_names`, starting at the ``k``-th), then waits
    until every worker has done its share, so that no loop is compiled twice on a machine
    that has never run attopt (each worker would otherwise compile nearly all of them as
    its tests reach them).  Loops already compiled are loaded from numba's cache.  A
    static split, not the sweep's pool of one task per loop
    (:func:`attopt.solvers.compilation.compile_loops`): the xdist workers are already
    the processes, and a pool would start and import two more at every run (5-10 s when
    every loop is cached)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if worker is None or count < 2:
        return
    from attopt.solvers.compilation import compile_loop, loop_names

    index = int(worker.removeprefix("gw"))
    done = Path(session.config._tmp_path_factory.getbasetemp()).parent / "numba-warm-up"
    try:
        for name in loop_names()[index::count]:
            compile_loop(name)
    finally:  # a worker whose share failed does not keep the others waiting
        done.mkdir(exist_ok=True)
        (done / worker).touch()
    deadline = time.monotonic() + WARM_UP_WAIT_S
    while len(list(done.iterdir())) < count and time.monotonic() < deadline:
        time.sleep(0.2)
