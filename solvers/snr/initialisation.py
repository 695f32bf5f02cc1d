"""Starting points of the one-step SNR solvers (NLSE, NLP), with or without a prior.

The SNR loss (Liu et al. 2023 eq. 19) is not convex in the attitude, so a local
solver needs a start in the basin of the global minimum.

* With a prior (the previous epoch's estimate while tracking, or a caller's
  a-priori attitude) the local solver starts there.  If that solve fails
  (e.g. the prior puts an observation behind an antenna, where the model is
  not finite), the epoch is initialised as without a prior.
* Without a prior (first epoch, after a gap): from the deterministic two-step
  solution of Liu et al. 2023 sec. 3.2 (:mod:`attopt.solvers.snr.deterministic`) when it is
  valid and the local solve from it converges; otherwise by multi-start from
  the fixed set :data:`START_ATTITUDES` around nadir pointing, keeping the
  converged solve of lowest loss.

:func:`initialise` and :func:`multistart` take any problem and local solver,
with the direct start and the multi-start set as arguments (the MAP NLP,
:mod:`attopt.solvers.map_nlp`, has no direct start and multi-starts from
well-spread attitudes).

:class:`Initialised` records which start won (``source``: 0 prior,
1 deterministic, 2 multi-start; ``start_index`` into :data:`START_ATTITUDES`),
how many starts converged and to how many distinct minima (attitudes more
than :data:`DISTINCT_MINIMUM_RAD` apart).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import TypeVar

import numpy as np
from casadi import Function
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.conventions import attitude_from_euler321
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.nlpsol import ACCEPTABLE_STATUS, ACCEPTED_STATUSES, NlpOptions
from attopt.solvers.snr.deterministic import two_step

START_YAWS_DEG = tuple(range(0, 360, 45))
"""Yaw of the multi-start attitudes (deg)."""
START_TILTS_DEG = ((0.0, 0.0), (0.0, 20.0), (0.0, -20.0))
"""(pitch, roll) pairs of the multi-start attitudes (deg)."""
START_ATTITUDES = attitude_from_euler321(
    *np.radians([(yaw, pitch, roll) for yaw in START_YAWS_DEG for pitch, roll in START_TILTS_DEG]).T
)
"""24 starts around nadir pointing: every 45 deg of yaw, each level and rolled
by +-20 deg (3-2-1 Euler angles of Liu et al. 2023 eq. 8).  An Earth-pointing
spacecraft without a prior may have any yaw, while roll and pitch stay small;
roll is the tilt that moves both cross-track main lobes (Liu et al. 2023 fig. 7).
In a trial of 40 noise-free epochs (16 observations, yaw anywhere, roll and
pitch within 14 deg) the NLP converged from 9-12 of the 24 starts, always to
the truth; most other starts put an observation behind an antenna
(``Invalid_Number_Detected``)."""
DISTINCT_MINIMUM_RAD = 1e-4
"""Converged attitudes farther apart than this are different local minima."""


class StartSource(IntEnum):
    PRIOR = 0
    DETERMINISTIC = 1
    MULTISTART = 2


@dataclass(frozen=True)
class LocalResult:
    """One local solve from one start.

    Attributes:
        attitude: the final iterate.
        loss: Liu et al. 2023 eq. 19 (weighted) at ``attitude``.
        converged: whether the solver reports convergence.
        status: the solver's status text.
        iterations: iterations of the solver.
        acceptable: converged only to the solver's relaxed ("acceptable") tolerance.
    """

    attitude: Rotation
    loss: float
    converged: bool
    status: str
    iterations: int
    acceptable: bool = False


def increment_solve(
    solver: Callable[[NlpOptions], Function],
    options: NlpOptions,
    parameters: NDArray[np.float64],
    start: Rotation,
) -> LocalResult:
    """One local solve of an NLP in the attitude increment ``v`` about ``start`` from
    ``v = 0`` (``A = C(v) start``, ``C(v)`` the rotation with MRPs ``v / 4``, pinned in
    tests/test_snr_model.py; :mod:`attopt.solvers.snr.nlp`) by ``solver(options)``, the
    NLP's ``nlpsol`` with ``parameters``.  A ``sqpmethod`` solve that stopped without
    converging after at least one iteration is repeated by IPOPT, whose line search cuts
    back steps into the regions where the loss is undefined (:mod:`attopt.solvers.nlpsol`);
    one that stopped at the start (the loss or its derivatives undefined there, where
    IPOPT stops too) is not."""
    nlp = solver(options)
    solution = nlp(x0=np.zeros(3), p=parameters)
    stats = nlp.stats()
    status = str(stats["return_status"])
    v = solution["x"].full().ravel()
    loss = float(solution["f"])
    finite = bool(np.all(np.isfinite(v)) and np.isfinite(loss))
    converged = finite and status in ACCEPTED_STATUSES
    iterations = int(stats["iter_count"])
    if not converged and iterations > 0 and options.solver != "ipopt":
        rescue = increment_solve(solver, replace(options, solver="ipopt"), parameters, start)
        if rescue.converged:
            return rescue
        return replace(rescue, status=f"{rescue.status} (IPOPT, after SQP's {status})")
    return LocalResult(
        attitude=Rotation.from_mrp(v / 4.0) * start if finite else start,
        loss=loss if finite else np.nan,
        converged=converged,
        status=status,
        iterations=iterations,
        acceptable=status == ACCEPTABLE_STATUS,
    )


Problem = TypeVar("Problem")
LocalSolve = Callable[[Problem, Rotation], LocalResult]
"""A local solver: problem (an epoch) and start attitude -> :class:`LocalResult`."""


@dataclass(frozen=True)
class Initialised:
    """The local solve an epoch's estimate comes from, and how it was started."""

    result: LocalResult
    source: StartSource
    start_index: int = -1
    starts_converged: int = 1
    distinct_minima: int = 1
    local_solves: int = 1

    def diagnostics(self) -> dict[str, float]:
        """Values of :data:`INITIALISATION_DIAGNOSTICS`."""
        values = (
            self.result.iterations,
            self.result.acceptable,
            self.source,
            self.start_index,
            self.starts_converged,
            self.distinct_minima,
            self.local_solves,
        )
        return {k: float(v) for k, v in zip(INITIALISATION_DIAGNOSTICS, values, strict=True)}


INITIALISATION_DIAGNOSTICS = (
    "iterations",
    "acceptable",
    "start_source",
    "start_index",
    "starts_converged",
    "distinct_minima",
    "local_solves",
)
"""Diagnostics of :meth:`Initialised.diagnostics`: iterations of the winning local
solve, whether it only reached the acceptable tolerance, its start (source and
multi-start index), converged starts, distinct minima and local solves run."""


def count_distinct(attitudes: list[Rotation], tolerance: float = DISTINCT_MINIMUM_RAD) -> int:
    """Number of clusters of ``attitudes`` (greedy, by rotation angle between them)."""
    representatives: list[Rotation] = []
    for attitude in attitudes:
        if all((attitude * r.inv()).magnitude() > tolerance for r in representatives):
            representatives.append(attitude)
    return len(representatives)


def multistart(
    problem: Problem,
    local_solve: LocalSolve[Problem],
    already: int = 0,
    starts: Rotation = START_ATTITUDES,
) -> Initialised:
    """Local solves from every one of ``starts``; the converged one of lowest loss wins.

    If none converges, the result is the (failed) solve of lowest loss, or the
    first, so that its status explains the failure.  ``already``: local solves
    run before (counted in :attr:`Initialised.local_solves`).
    """
    results = [local_solve(problem, starts[i]) for i in range(len(starts))]
    converged = [i for i, r in enumerate(results) if r.converged and np.isfinite(r.loss)]
    finite = [i for i, r in enumerate(results) if np.isfinite(r.loss)]
    candidates = converged or finite or [0]
    best = min(candidates, key=lambda i: results[i].loss if np.isfinite(results[i].loss) else 0.0)
    return Initialised(
        result=results[best],
        source=StartSource.MULTISTART,
        start_index=best,
        starts_converged=len(converged),
        distinct_minima=count_distinct([results[i].attitude for i in converged]),
        local_solves=already + len(results),
    )


AMBIGUITY_PROBABILITY = 1e-4
"""Tail probability of the chi-square(3) quantile of :func:`rival_minimum` (21.1)."""
AMBIGUITY_QUANTILE = float(chi2.isf(AMBIGUITY_PROBABILITY, 3))


def rival_minimum(
    problem: Problem,
    local_solve: LocalSolve[Problem],
    attitude: Rotation,
    loss: float,
    covariance: np.ndarray,
    starts: Rotation = START_ATTITUDES,
) -> tuple[float, float] | None:
    """A second local minimum the data cannot tell from the estimate ``attitude`` (its
    local solve's ``loss``, its ``covariance``), or ``None``.

    Local solves from every one of ``starts``; a converged one is a rival when its
    loss is within the chi-square(3) ``1 - AMBIGUITY_PROBABILITY`` quantile ``q`` of
    the estimate's (``2 (L_r - L_b) <= q``: the likelihood ratio cannot reject it; lower
    losses count too) and it lies outside the estimate's covariance (``d^T P^-1 d >
    q``, ``d`` the rotation vector from the estimate to it).  Returns the rival of lowest loss as
    ``(angle in degrees, 2 (L_r - L_b))``.  The covariance describes one basin only:
    with weak data (few SNRs, wide sigmas) the SNR loss can have a second minimum tens
    of degrees away that fits as well (measured in ``adsb-sky``'s modelled sky: 54 deg
    away with a lower loss, ``2 dL = -0.8``).
    """
    quantile = AMBIGUITY_QUANTILE
    rivals = []
    for i in range(len(starts)):
        result = local_solve(problem, starts[i])
        if not (result.converged and np.isfinite(result.loss)):
            continue
        gap = 2.0 * (result.loss - loss)
        d = (result.attitude * attitude.inv()).as_rotvec()
        with np.errstate(invalid="ignore", over="ignore"):
            distance = float(d @ np.linalg.lstsq(covariance, d, rcond=None)[0])
        if gap <= quantile and not distance <= quantile:
            rivals.append((gap, float(np.degrees(np.linalg.norm(d)))))
    if not rivals:
        return None
    gap, angle = min(rivals)
    return angle, gap


def two_step_start(problem: SnrEpoch) -> Rotation | None:
    """The deterministic two-step solution of Liu et al. 2023 sec. 3.2, if it is valid."""
    return two_step(problem).attitude


def initialise(
    problem: Problem,
    local_solve: LocalSolve[Problem],
    prior: Rotation | None,
    direct_start: Callable[[Problem], Rotation | None] | None = two_step_start,
    starts: Rotation = START_ATTITUDES,
) -> Initialised:
    """The local solve of an epoch, started as the module docstring describes.

    ``direct_start`` gives the start tried after the prior (for SNR epochs
    :func:`two_step_start`; ``None``: none), ``starts`` the multi-start set.
    If no start converges, the result is the failed solve of the first start
    tried (the prior, else the direct start, else the best multi-start),
    whose status then explains the failure.
    """
    failed: list[tuple[LocalResult, StartSource]] = []
    if prior is not None:
        result = local_solve(problem, prior)
        if result.converged:
            return Initialised(result, StartSource.PRIOR)
        failed.append((result, StartSource.PRIOR))
    direct = None if direct_start is None else direct_start(problem)
    if direct is not None:
        result = local_solve(problem, direct)
        if result.converged:
            return Initialised(result, StartSource.DETERMINISTIC, local_solves=len(failed) + 1)
        failed.append((result, StartSource.DETERMINISTIC))
    started = multistart(problem, local_solve, already=len(failed), starts=starts)
    if started.result.converged or not failed:
        return started
    first, source = failed[0]
    return Initialised(
        first, source, starts_converged=0, distinct_minima=0, local_solves=started.local_solves
    )
