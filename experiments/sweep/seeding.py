"""Per-trial random seeds that do not depend on how the sweep is executed.

Trial ``j`` of setting ``i`` always draws from
``SeedSequence(root, spawn_key=(i, j))``, whichever engine, worker or chunk
runs it, so results are bitwise identical across engines and worker counts,
and a single trial can be replayed from its two indices.
"""

from __future__ import annotations

import numpy as np


def trial_seed(root: int, setting_index: int, trial_index: int) -> np.random.SeedSequence:
    """Return the seed sequence of trial ``trial_index`` of setting ``setting_index``."""
    return np.random.SeedSequence(root, spawn_key=(setting_index, trial_index))


def trial_index(seed: np.random.SeedSequence) -> int:
    """Return ``j`` of a seed made by :func:`trial_seed` (0 for a seed without spawn key).

    For experiments that do costly extra work in the first trials of a setting
    only: the choice then depends on the trial, never on the engine.
    """
    return int(seed.spawn_key[-1]) if seed.spawn_key else 0


def describe_seed(root: int, setting_index: int, trial_index: int) -> str:
    """Return Python source that rebuilds the trial's seed sequence (for failure records)."""
    return f"SeedSequence({root}, spawn_key=({setting_index}, {trial_index}))"


def check_root_seed(root: int) -> int:
    """Return ``root`` if it is a valid root seed (a non-negative int), else raise ValueError."""
    if isinstance(root, bool) or not isinstance(root, int) or root < 0:
        raise ValueError(f"seed must be a non-negative integer, got {root!r}")
    return root
