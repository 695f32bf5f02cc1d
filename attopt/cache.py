"""attopt's cache directory on this machine, shared by every on-disk cache.

Two caches live in it: scenario geometry
(:mod:`attopt.experiments.environment.disk_cache`) and compiled measurement
kernels (:mod:`attopt.formulations.kernels`).

``$ATTOPT_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/attopt`` (default
``~/.cache/attopt``); ``ATTOPT_CACHE_DIR=off`` (any case) disables both.

Example::

    >>> import os
    >>> from attopt.cache import cache_directory
    >>> os.environ["ATTOPT_CACHE_DIR"] = "off"
    >>> cache_directory() is None
    True
"""

from __future__ import annotations

import os
from pathlib import Path

CACHE_DIR_ENV = "ATTOPT_CACHE_DIR"
"""Environment variable naming the cache directory, or :data:`DISABLED`."""
DISABLED = "off"
"""Value of :data:`CACHE_DIR_ENV` (any case) that turns the caches off."""


def cache_directory() -> Path | None:
    """The cache directory (module docstring), ``None`` when the caches are disabled."""
    configured = os.environ.get(CACHE_DIR_ENV, "")
    if configured.lower() == DISABLED:
        return None
    if configured:
        return Path(configured).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "attopt"
