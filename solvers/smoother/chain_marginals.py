"""Marginal covariances of a Gaussian factor graph by a backward sweep over its Bayes net.

``gtsam.GaussianBayesTree.jointMarginalCovariance`` recomputes separator
marginals clique by clique, which for the smoother with transmitter offsets
(separators of the 100-300 offsets in view, :func:`solvers.smoother.batch._time_ordering`)
costs tens of seconds for a few minutes of pass.  Here the graph is
eliminated sequentially in the given ordering into conditionals
``R x_F + S x_P = d`` (unit noise after elimination, checked), and the
covariances are propagated from the last eliminated variable back to the
first (the Rauch-Tung-Striebel recursion on a Bayes net, "selected
inversion")::

    K = R^-1 S,  Cov(F, A) = -K Cov(P, A),  Cov(F) = R^-1 R^-T - Cov(F, P) K^T,

where ``A`` is the active set: the variables already swept that some
conditional still to come has as a parent, or whose joint with a variable
still to come is requested.  Only the dense joint covariance of the active
set is kept (its size is the separator's), so the sweep costs
``O(n s^2)`` for ``n`` variables and separators of dimension ``s``.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular

Array = NDArray[np.float64]


class _ActiveCovariance:
    """Dense joint covariance of the active variables, each in its own slots of a square matrix.

    Freed slots keep stale values; every read goes through the slots of active variables.
    """

    def __init__(self, capacity: int) -> None:
        self.matrix = np.zeros((capacity, capacity))
        self.slots: dict[int, NDArray[np.intp]] = {}
        self.free = list(range(capacity - 1, -1, -1))

    def index(self, keys: Sequence[int]) -> NDArray[np.intp]:
        """Slots of ``keys``, concatenated in order."""
        if not keys:
            return np.zeros(0, np.intp)
        return np.concatenate([self.slots[k] for k in keys])

    def add(self, key: int, size: int) -> NDArray[np.intp]:
        """Reserve ``size`` slots for ``key`` (growing the matrix when full)."""
        if len(self.free) < size:
            old = self.matrix.shape[0]
            new = max(2 * old, old + size)
            grown = np.zeros((new, new))
            grown[:old, :old] = self.matrix
            self.matrix = grown
            self.free = list(range(new - 1, old - 1, -1)) + self.free
        slots = np.array([self.free.pop() for _ in range(size)], dtype=np.intp)
        self.slots[key] = slots
        return slots

    def drop(self, key: int) -> None:
        """Release ``key``'s slots."""
        self.free.extend(self.slots.pop(key).tolist())


def _unit_conditional(conditional: gtsam.GaussianConditional) -> tuple[Array, Array, Array]:
    """Copies of ``R``, ``S`` (all parents) and ``d``, after checking the noise is unit."""
    model = conditional.get_model()
    if model is not None and not np.array_equal(model.sigmas(), np.ones(model.dim())):
        raise ValueError(f"conditional with non-unit noise sigmas {model.sigmas()}")
    r = np.array(conditional.R(), dtype=float, copy=True)
    s = np.array(conditional.S(), dtype=float, copy=True)
    d = np.array(conditional.d(), dtype=float, copy=True)
    return r, s, d


def _joint_marginals(
    linear: gtsam.GaussianFactorGraph,
    ordering: gtsam.Ordering,
    groups: Sequence[Sequence[int]],
) -> list[Array]:
    """Joint marginal covariance of each group of keys (rows and columns in the group's key order).

    ``ordering`` must hold every key of ``linear`` and is used as the
    sequential elimination order; separators (and so the cost) are those of
    that order.  Raises ``ValueError`` when a conditional is not unit-noise
    (a constrained factor), ``RuntimeError`` (GTSAM's) when the system is singular.
    """
    bayes_net = linear.eliminateSequential(ordering)
    size = bayes_net.size()
    frontal = [bayes_net.at(i).firstFrontalKey() for i in range(size)]
    position = {key: i for i, key in enumerate(frontal)}
    release = list(range(size))  # last sweep step (lowest position) at which a key is needed
    for i in range(size):
        for key in bayes_net.at(i).keys()[1:]:
            p = position[key]
            release[p] = min(release[p], i)
    due: dict[int, list[int]] = {}  # step -> groups complete after it
    for g, group in enumerate(groups):
        first = min(position[k] for k in group)
        due.setdefault(first, []).append(g)
        for k in group:
            release[position[k]] = min(release[position[k]], first)
    dropped: dict[int, list[int]] = {}
    for p, step in enumerate(release):
        dropped.setdefault(step, []).append(frontal[p])

    active = _ActiveCovariance(64)
    out: list[Array] = [np.zeros((0, 0))] * len(groups)
    for i in range(size - 1, -1, -1):
        conditional = bayes_net.at(i)
        parents = list(conditional.keys()[1:])
        r, s, _ = _unit_conditional(conditional)
        del conditional
        rows = active.index(parents)
        inverse = solve_triangular(r, np.eye(r.shape[0]))
        gain = inverse @ s
        slots = active.add(frontal[i], r.shape[0])
        cross = -gain @ active.matrix[rows]  # zero without parents: independent of the rest
        active.matrix[slots, :] = cross
        active.matrix[:, slots] = cross.T
        active.matrix[np.ix_(slots, slots)] = inverse @ inverse.T - cross[:, rows] @ gain.T
        for g in due.get(i, ()):
            index = active.index(groups[g])
            out[g] = active.matrix[np.ix_(index, index)].copy()
        for key in dropped.get(i, ()):
            active.drop(key)
    return out


def sequential_marginals(
    linear: gtsam.GaussianFactorGraph,
    ordering: gtsam.Ordering,
    node_keys: Sequence[tuple[int, int]],
    offset_keys: Sequence[int],
) -> tuple[Array, Array]:
    """Joint covariances ``(n, 6, 6)`` of each node's ``(attitude, bias)`` keys (the attitude
    first, cross blocks included) and the variances ``(n_offsets,)`` of the 1-dimensional
    ``offset_keys``, eliminating ``linear`` sequentially in ``ordering`` (module docstring)."""
    groups = [list(pair) for pair in node_keys] + [[key] for key in offset_keys]
    joints = _joint_marginals(linear, ordering, groups)
    nodes = np.array(joints[: len(node_keys)]).reshape(len(node_keys), 6, 6)
    variances = np.array([c[0, 0] for c in joints[len(node_keys) :]])
    return nodes, variances
