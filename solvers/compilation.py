"""Compile attopt's numba loops ahead of the work, once per machine, split across workers.

numba compiles a loop on its first call and caches the machine code on disk
(:func:`attopt.formulations.kernels.first_call`); later processes load it in a fraction
of a second.  On a machine that has never run attopt, a sweep's workers would all reach
the same loops at the same moment and each compile every one of them (the Wahba
solvers' five loops take 8-15 s each), so the first run paid the whole compilation once
per worker.  :func:`compile_loops` instead hands each loop to one worker, as a task of
its own: the pool gives the next loop to whichever worker is free, the largest first,
and the others load it from the cache when their trials need it.  The sweep runner
does it for the loops an experiment declares
(:attr:`attopt.experiments.experiment.Experiment.compiled_loops`) before its first
trial; ``attopt compile`` does it for every loop.

Each loop's warm-up (:data:`~attopt.formulations.kernels.WARM_UPS`) calls it on a small
input of the types its callers pass, so the trials find exactly what was compiled.

Example::

    >>> from attopt.solvers.compilation import loop_names
    >>> loop_names(["wahba.quest", "smoother"])
    ['wahba.quest', 'smoother.chain_rule', 'smoother.offsets_downdate', 'smoother.perturbations']
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import Executor

from attopt.formulations.kernels import WARM_UPS, compiled_loops

LOOP_MODULES = (
    "attopt.solvers.wahba.compiled",
    "attopt.formulations.kernel_calls",
    "attopt.solvers.filters.compiled",
    "attopt.solvers.filters.update_kernels",
    "attopt.solvers.filters.vector_update",
    "attopt.solvers.filters.vector_unscented_update",
    "attopt.formulations.geodesic",
    "attopt.solvers.smoother.difference_kernels",
    "attopt.solvers.smoother.compiled",
)
"""The modules that define numba functions; those with loops of their own register their
warm-ups (:mod:`attopt.formulations.kernel_calls` has none: its call is compiled into
the loops that use it)."""
SLOWEST = ("vectors.mekf_update", "vectors.usque_update", "wahba")
"""The loops that take longest to compile (8-25 s each), handed out first."""


def loop_names(selection: Iterable[str] = ("",)) -> list[str]:
    """The registered loops whose name is one of ``selection`` or starts with one of its
    entries and a dot (``"wahba"``: the five Wahba loops; ``""``: every loop), the
    :data:`SLOWEST` (names or prefixes) first, each part in alphabetical order.  Raises
    ``KeyError`` for an entry that names no loop."""
    selection = list(selection)
    for module in LOOP_MODULES if selection else ():
        importlib.import_module(module)
    chosen: list[str] = []
    for entry in selection:
        matches = [n for n in WARM_UPS if not entry or n == entry or n.startswith(entry + ".")]
        if not matches:
            raise KeyError(f"no numba loop named {entry!r}; loops: {', '.join(WARM_UPS)}")
        chosen += [n for n in matches if n not in chosen]
    slowest = [n for n in chosen if any(n == s or n.startswith(s + ".") for s in SLOWEST)]
    return sorted(chosen, key=lambda n: (n not in slowest, n))


def compile_loop(name: str) -> float:
    """Compile (or load from numba's cache) the loop ``name`` in this process: the
    seconds its warm-up took; nothing to do when the loops are disabled
    (``ATTOPT_KERNELS=interpreted``)."""
    if not compiled_loops():
        return 0.0
    loop_names([name])
    start = time.perf_counter()
    WARM_UPS[name]()
    return time.perf_counter() - start


def compile_loops(
    selection: Iterable[str] = ("",), executor: Executor | None = None
) -> dict[str, float]:
    """Compile the loops of ``selection`` (:func:`loop_names`), one task per loop on
    ``executor`` (a process pool or a Dask client's executor; ``None``: one after another
    in this process): each loop's seconds, in the order of :func:`loop_names`."""
    names: Sequence[str] = loop_names(selection)
    if executor is None:
        return {name: compile_loop(name) for name in names}
    futures = [executor.submit(compile_loop, name) for name in names]
    return {name: future.result() for name, future in zip(names, futures, strict=True)}
