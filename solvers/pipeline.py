"""Run several estimators on one pass, each once, starting each from the track it needs.

Some pass estimators start from another's track: the RTS pass smooths an
MEKF's, the batch smoother starts from the online smoother's or the RTS
pass's, the batch least squares from an RTS pass (their ``starts_from``,
:class:`~attopt.solvers.estimator.PassEstimator`).  :func:`run_estimators`
runs what is asked for on the same pass, runs every estimator at most once,
hands each the first of its ``starts_from`` that was asked for (else it runs
the last one, unreported, as its start), and times each run; a run's time
includes the time of the run it started from, as a flight pipeline would pay
it.

Example::

    >>> runs = run_estimators(my_pass, {"mekf": "mekf", "rts": "rts"})  # doctest: +SKIP
    >>> runs["rts"].track, runs["rts"].seconds  # doctest: +SKIP
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from attopt.formulations.passes import Pass
from attopt.solvers.estimator import Estimator, PassEstimator
from attopt.solvers.registry import estimator as registered
from attopt.solvers.results import Track


@dataclass(frozen=True)
class Run:
    """One estimator's track on a pass and the wall time (s) it took, its start's included.

    Example::

        >>> import numpy as np
        >>> from attopt import Pass, Snapshot, run_estimators
        >>> vectors = np.eye(3)[:2]
        >>> one_epoch = Pass([0.0], [Snapshot.from_vectors(vectors, vectors, 1e-3)])
        >>> run = run_estimators(one_epoch, ["svd"])["svd"]
        >>> run.track.method, run.seconds > 0
        ('svd', True)
    """

    track: Track
    seconds: float


def run_estimators(
    pass_: Pass,
    methods: Mapping[str, str | Estimator] | Sequence[str],
    starts: Mapping[str, Run] | None = None,
) -> dict[str, Run]:
    """Each method's :class:`Run` on ``pass_``, keyed as asked (module docstring).

    Args:
        pass_: the pass every estimator sees.
        methods: row label -> registry name or estimator instance (a sequence
            of registry names labels each by its name).
        starts: label -> a run that estimator starts from instead of its
            ``starts_from`` (for example a start computed elsewhere).

    Raises:
        KeyError: an unknown registry name.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import MEMS_GYRO, GyroRecord, Pass, Prior, run_estimators
        >>> gyro = GyroRecord(np.arange(51) / 10.0, np.zeros((50, 3)), MEMS_GYRO)
        >>> v = np.eye(3)[:2]
        >>> prior = Prior(Rotation.identity(), 1e-4 * np.eye(3))
        >>> pass_ = Pass.from_vectors(np.arange(5.0), np.tile(v, (5, 1, 1)), v, 1e-3, gyro, prior)
        >>> runs = run_estimators(pass_, {"filter": "mekf", "smoother": "rts", "wahba": "quest"})
        >>> [run.track.method for run in runs.values()]
        ['mekf', 'rts', 'quest']
    """
    wanted = dict(methods) if isinstance(methods, Mapping) else {m: m for m in methods}
    chosen = {label: registered(m) if isinstance(m, str) else m for label, m in wanted.items()}
    by_name = {e.name: label for label, e in chosen.items()}
    done: dict[str, Run] = {}

    def run(label: str, est: Estimator) -> Run:
        if label in done:
            return done[label]
        start_run = (starts or {}).get(label)
        if start_run is None and isinstance(est, PassEstimator) and est.starts_from:
            start_run = _start(est)
        begin = time.perf_counter()
        if isinstance(est, PassEstimator):
            track = est.solve(pass_, None if start_run is None else start_run.track)
        else:
            track = est.solve_pass(pass_)
        seconds = time.perf_counter() - begin + (0.0 if start_run is None else start_run.seconds)
        done[label] = Run(track, seconds)
        return done[label]

    def _start(est: PassEstimator) -> Run:
        for name in est.starts_from:
            if name in by_name:
                return run(by_name[name], chosen[by_name[name]])
        fallback = est.starts_from[-1]
        return run(f"_start:{fallback}", registered(fallback))

    return {label: run(label, est) for label, est in chosen.items()}
