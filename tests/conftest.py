"""Test configuration.

* Hypothesis runs derandomised under CI so a CI run is reproducible.
* The on-disk geometry cache (``experiments/environment/disk_cache.py``) lives in the
  run's temporary directory, never in the user's cache (below).
"""

from __future__ import annotations

import os

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
