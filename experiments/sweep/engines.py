"""Execution engines: in-process, a local process pool, or Dask.

Every engine runs :func:`~attopt.experiments.sweep.tasks.run_chunk` on plain
:class:`~attopt.experiments.sweep.tasks.ChunkSpec` objects and yields
``(spec, outcome)`` pairs as chunks finish, where ``outcome`` is the
:class:`~attopt.experiments.sweep.tasks.ChunkResult` or the exception that prevented
the chunk from finishing (a dead worker, a missing module on a worker...).
Such a chunk is not stored, so rerunning the sweep retries it.

Engines are context managers; leaving the ``with`` block on an exception
(including Ctrl-C) cancels the chunks still queued and stops the workers.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import pkgutil
import signal
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed, wait
from types import TracebackType
from typing import Any

from attopt.experiments.sweep.tasks import ChunkResult, ChunkSpec, run_chunk
from attopt.solvers.compilation import compile_loop

ENGINES = ("local", "dask")
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)

WORKER_WAIT_S = 60
"""How long to wait for a first worker to join an existing Dask scheduler."""

Outcome = tuple[ChunkSpec, ChunkResult | BaseException]


class EngineSetupError(ValueError):
    """The engine cannot run the sweep: bad name or options, or unusable Dask workers."""


class Engine:
    """Runs chunks in this process, one after another; the base of the other engines."""

    workers = 1

    def __enter__(self) -> Engine:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Release the engine's workers (nothing to release in process)."""

    def run(self, specs: Sequence[ChunkSpec], loops: Sequence[str] = ()) -> Iterator[Outcome]:
        """Run the chunks one after another in this process (``loops``, the numba loops
        the other engines compile first, are compiled here on first use: the same cost)."""
        for spec in specs:
            try:
                outcome: ChunkResult | BaseException = run_chunk(spec)
            except Exception as error:
                outcome = error
            yield spec, outcome


class LocalEngine(Engine):
    """A pool of spawned processes on this machine, one BLAS/OpenMP thread each."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._executor: ProcessPoolExecutor | None = None
        self._processes: list[multiprocessing.process.BaseProcess] = []

    def run(self, specs: Sequence[ChunkSpec], loops: Sequence[str] = ()) -> Iterator[Outcome]:
        """Compile the numba ``loops``, one task each
        (:func:`~attopt.solvers.compilation.compile_loop`, taken by whichever worker is
        free), then submit every chunk to the pool and yield outcomes in completion order."""
        before = set(multiprocessing.active_children())
        # The pool spawns its workers on submit, before they import numpy.
        with _spawning_workers():
            self._executor = ProcessPoolExecutor(
                max_workers=self.workers, mp_context=multiprocessing.get_context("spawn")
            )
            warm_ups = [self._executor.submit(compile_loop, name) for name in loops]
        self._processes = [p for p in multiprocessing.active_children() if p not in before]
        wait(warm_ups)  # a loop that failed to compile fails again in the trials that use it
        with _spawning_workers():  # the pool may start more workers on these submits
            futures: dict[Future[ChunkResult], ChunkSpec] = {
                self._executor.submit(run_chunk, spec): spec for spec in specs
            }
        self._processes = [p for p in multiprocessing.active_children() if p not in before]
        for future in as_completed(futures):
            spec = futures.pop(future)
            error = future.exception()
            yield spec, error if error is not None else future.result()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Shut the pool down; on an exception, cancel queued chunks and stop the workers."""
        if self._executor is None:
            return
        if exc_type is None:
            self._executor.shutdown(wait=True)
            return
        self._executor.shutdown(wait=False, cancel_futures=True)
        for process in self._processes:
            process.terminate()
        for process in self._processes:
            process.join()


class DaskEngine(Engine):
    """A Dask cluster: a new LocalCluster, or an existing scheduler at ``address``."""

    def __init__(self, workers: int | None, address: str | None) -> None:
        if address is not None and workers is not None:
            raise EngineSetupError(
                "--workers sets the size of a local cluster; with --address the "
                "cluster's own workers are used"
            )
        self.workers = workers or os.cpu_count() or 1
        self.address = address
        self._cluster: Any = None
        self._client: Any = None
        self._pending: list[Any] = []

    def __enter__(self) -> DaskEngine:
        """Start the LocalCluster (unless an address was given) and connect to it."""
        from distributed import Client, LocalCluster

        if self.address is None:
            with _spawning_workers():
                self._cluster = LocalCluster(
                    n_workers=self.workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
            self._client = Client(self._cluster)
        else:
            try:
                self._client = Client(self.address)
                self._client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except (OSError, TimeoutError) as error:
                self.__exit__(type(error), error, None)
                raise EngineSetupError(
                    f"no usable Dask cluster at {self.address}: {error}"
                ) from error
            self.workers = len(self._client.scheduler_info()["workers"])
        return self

    def run(self, specs: Sequence[ChunkSpec], loops: Sequence[str] = ()) -> Iterator[Outcome]:
        """Compile the numba ``loops``, each in one worker (workers on one machine share
        numba's cache), then submit every chunk to the cluster and yield outcomes in
        completion order."""
        from distributed import as_completed as dask_as_completed
        from distributed import wait as dask_wait

        if specs:
            self._check_workers_import(specs[0].experiment)
        dask_wait([self._client.submit(compile_loop, name, pure=False) for name in loops])
        futures = {self._client.submit(run_chunk, spec, pure=False): spec for spec in specs}
        self._pending = list(futures)
        for future in dask_as_completed(self._pending):
            spec = futures.pop(future)
            try:
                outcome: ChunkResult | BaseException = future.result()
            except Exception as error:  # the task's, or a lost worker or result
                outcome = error
            future.release()
            yield spec, outcome

    def _check_workers_import(self, reference: str) -> None:
        """Fail early if a worker cannot import the experiment (it would die on its tasks)."""
        try:
            # A stdlib function and a string: the check itself needs nothing from attopt.
            self._client.run(pkgutil.resolve_name, f"{reference}.name")
        except Exception as error:
            raise EngineSetupError(
                f"a Dask worker cannot import {reference}: {type(error).__name__}: {error} "
                "(install attopt and its dependencies, same versions, on every worker)"
            ) from error

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Cancel what is still queued and close the client (and the LocalCluster)."""
        if self._client is not None:
            if exc_type is not None:
                with contextlib.suppress(Exception):
                    self._client.cancel(self._pending)
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_engine(name: str, *, workers: int | None, address: str | None) -> Engine:
    """Return the engine ``name`` ("local" or "dask").

    ``local`` with one worker runs in this process; ``workers`` defaults to the
    number of CPUs.  ``address`` is only meaningful for ``dask``.
    """
    if name not in ENGINES:
        raise EngineSetupError(f"unknown engine {name!r}; choose one of {', '.join(ENGINES)}")
    if workers is not None and workers < 1:
        raise EngineSetupError(f"workers must be at least 1, got {workers}")
    if name == "dask":
        return DaskEngine(workers, address)
    if address is not None:
        raise EngineSetupError("--address is only used with --engine dask")
    count = workers or os.cpu_count() or 1
    return Engine() if count == 1 else LocalEngine(count)


@contextlib.contextmanager
def _spawning_workers() -> Iterator[None]:
    """Give worker processes spawned inside the block one BLAS thread and no SIGINT.

    Spawned processes inherit the environment and ignored signals.  Ignoring
    Ctrl-C in the workers leaves it to this process, which cancels the queue
    and stops them cleanly instead of every worker printing a traceback.
    """
    saved = {key: os.environ.get(key) for key in THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    in_main_thread = threading.current_thread() is threading.main_thread()
    if in_main_thread:
        handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        if in_main_thread:
            signal.signal(signal.SIGINT, handler)
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
