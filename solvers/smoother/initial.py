"""Where the batch smoother starts: a track on the pass's epochs, turned into node values.

The start (:class:`Start`) is another estimator's track on the same epochs (the
registry's ``starts_from``: the online smoother's, else the RTS pass's), a track of
single-epoch solutions (:func:`single_frame_initial`), fixed values
(:func:`fixed_start`, e.g. the truth for the posterior bound), or, given none, a
filter run here (:func:`filter_start`): ``"mekf"`` runs the forward MEKF and its RTS
pass (:mod:`attopt.solvers.filters`), whose estimates are within the linearisation
range of the batch optimum; ``"gyro"`` integrates the gyro from the prior (cheap;
only for passes short enough, or gyros good enough, that the drift stays within the
measurement models' convergence range).

:func:`node_values` gives one estimate per node of the problem
(:func:`attopt.solvers.smoother.problem.pass_nodes`): the prior's at the prior node
(if any); where the start flags an epoch, the filter's raw estimate if its history
has one; where it leaves an epoch undetermined, gyro integration from the previous
node (Liu et al. 2023 eq. 25), gated with an attitude sigma of
:data:`~attopt.solvers.smoother.problem.UNDETERMINED_SIGMA`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import Pass, Prior
from attopt.solvers.filters.common import (
    STATE_SIZE,
    FilterOptions,
    GyroPass,
    propagate_attitude,
)
from attopt.solvers.filters.estimators import Mekf
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.results import Track
from attopt.solvers.sequential import FilterHistory
from attopt.solvers.smoother.conventions import Array
from attopt.solvers.smoother.problem import UNDETERMINED_SIGMA, NodeValues, pass_nodes

INITIALISATIONS = ("mekf", "gyro")
"""What :func:`filter_start` can run (module docstring)."""


@dataclass(frozen=True)
class Start:
    """A track on the pass's epochs to start from.

    Attributes:
        track: quaternions, biases and ``6 x 6`` state covariances (NaN where undetermined).
        history: the forward filter's history, whose raw estimates replace the
            epochs ``track`` flags (``None``: none).
        label: ``"mekf+rts"``, ``"gyro"`` or ``"given"`` (the report's ``initialisation``).
    """

    track: Track
    history: FilterHistory | None
    label: str


def filter_start(pass_: Pass, initialisation: str, options: FilterOptions) -> Start:
    """The start computed here, with the MEKF of fault rules ``options`` (module docstring)."""
    mekf = Mekf(filter=options)
    if initialisation == "mekf":
        forward = mekf.solve(pass_)
        return Start(rts_smooth(forward, options, "rts"), forward.history, "mekf+rts")
    forward = mekf.solve(replace(pass_, snapshots=(None,) * len(pass_)))
    return Start(forward, forward.history, "gyro")


def given_start(initial: Track, pass_: Pass) -> Start:
    """``initial`` (another estimator's track on ``pass_``) as the start.

    Raises:
        InvalidObservationError: it has another number of epochs.
    """
    if len(initial) != len(pass_):
        raise InvalidObservationError(
            f"initial estimate has {len(initial)} epochs, not {len(pass_)}"
        )
    return Start(initial, initial.history, "given")


def fixed_start(attitude: Rotation, bias: ArrayLike) -> Track:
    """A start at given attitudes ``(N,)`` and biases ``(N, 3)`` with no covariance (it
    gates with :data:`~attopt.solvers.smoother.problem.UNDETERMINED_SIGMA`)."""
    quaternion = attitude.as_quat().reshape(-1, 4)
    n = quaternion.shape[0]
    bias = np.broadcast_to(np.asarray(bias, dtype=float), (n, 3)).copy()
    return Track(
        method="fixed",
        quaternion=quaternion,
        covariance=np.full((n, 3, 3), np.nan),
        loss=np.full(n, np.nan),
        valid=np.ones(n, dtype=bool),
        reason=np.full(n, "", dtype=object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
        bias=bias,
        state_covariance=np.full((n, STATE_SIZE, STATE_SIZE), np.nan),
        state=("attitude", "bias"),
    )


def single_frame_initial(solution: Track, prior: Prior) -> Track:
    """A start from single-epoch solutions: their attitudes (same reference frame as
    the smoother's) where valid, the prior's bias everywhere; :func:`node_values`
    fills the other epochs by gyro integration from the previous node.  The
    covariance (used to gate the measurements) is the solution's attitude block and
    the prior's bias block (``prior``: ``[attitude, bias]``).
    """
    n = len(solution)
    covariance = np.full((n, STATE_SIZE, STATE_SIZE), np.nan)
    covariance[:, :3, :3] = solution.covariance
    covariance[:, :3, 3:] = covariance[:, 3:, :3] = 0.0
    covariance[:, 3:, 3:] = np.asarray(prior.covariance)[3:, 3:]
    quaternion = np.where(solution.valid[:, None], solution.quaternion, np.nan)
    return replace(
        solution,
        quaternion=quaternion,
        bias=np.tile(np.asarray(prior.bias, dtype=float), (n, 1)),
        state_covariance=covariance,
        state=("attitude", "bias"),
    )


def node_values(start: Start, inputs: GyroPass) -> NodeValues:
    """The start at every node of the pass's problem (module docstring)."""
    q = np.array(start.track.quaternion, dtype=float)
    b = np.array(start.track.bias, dtype=float)
    p = np.array(start.track.state_covariance, dtype=float)
    history = start.history
    if history is not None:  # epochs the track flags keep the filter's raw estimate
        missing = ~np.isfinite(q).all(axis=1)
        q[missing] = history.filtered_attitude[missing]
        b[missing] = history.filtered_vector[missing]
        p[missing] = history.filtered_covariance[missing]
    prior = inputs.prior
    nodes, offset = pass_nodes(inputs.gyro)
    if offset:
        q = np.vstack([prior.attitude.as_quat(), q])
        b = np.vstack([prior.bias, b])
        p = np.concatenate([np.asarray(prior.covariance)[None], p])
    return _filled(q, b, p, nodes, inputs)


def _filled(q: Array, b: Array, p: Array, nodes: Array, inputs: GyroPass) -> NodeValues:
    """Node estimates with undetermined ones filled by gyro integration from the previous node."""
    n = nodes.size
    gyro, prior = inputs.gyro, inputs.prior
    covariance = np.where(np.isfinite(p).all(axis=(1, 2))[:, None, None], p, np.nan)
    attitudes = np.full((n, 4), np.nan)
    bias = np.full((n, 3), np.nan)
    large = np.diag([UNDETERMINED_SIGMA**2] * 3 + [1.0] * 3)
    for k in range(n):
        ok = np.isfinite(q[k]).all() and np.isfinite(b[k]).all()
        if ok:
            attitudes[k], bias[k] = q[k], b[k]
        elif k == 0:
            attitudes[k], bias[k] = prior.attitude.as_quat(), prior.bias
            covariance[k] = prior.covariance
        else:
            begin, end = nodes[k - 1], nodes[k]
            a = propagate_attitude(
                Rotation.from_quat(attitudes[k - 1]),
                gyro.rates[begin:end] - bias[k - 1],
                gyro.dt[begin:end],
            )
            attitudes[k], bias[k] = a.as_quat(), bias[k - 1]
        if not np.isfinite(covariance[k]).all():
            covariance[k] = large
    return NodeValues(Rotation.from_quat(attitudes), bias, covariance)
