"""Marginal covariances of a Gaussian factor graph by a backward sweep over its Bayes net.

``gtsam.GaussianBayesTree.jointMarginalCovariance`` recomputes separator
marginals clique by clique, which for the smoother with transmitter offsets
(separators of the 100-300 offsets in view,
:func:`attopt.solvers.smoother.problem.time_ordering`) costs tens of seconds for a
few minutes of pass.  Here the graph is
eliminated sequentially in the given ordering into conditionals ``R x_F + S x_P = d``
(unit noise after elimination, checked), and the covariances are propagated
from the last eliminated variables back to the first (the Rauch-Tung-Striebel
recursion on a Bayes net, "selected inversion")::

    K = R^-1 S,  Cov(F, A) = -K Cov(P, A),  Cov(F) = R^-1 R^-T - Cov(F, P) K^T,

where ``A`` is the active set: the variables already swept that a
conditional still to come has as a parent, or whose joint with a variable
still to come is requested.  Only the dense joint covariance of the active
set is kept (its size is the separator's), so the sweep costs
``O(n s^2)`` for ``n`` variables and separators of dimension ``s``, as
the elimination itself (which dominates).  Multifrontal elimination with
the sweep over cliques root to leaves was measured no faster on the
adsb-snr passes (GTSAM builds the same dense separator factors).
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

Array = NDArray[np.float64]
Conditional = tuple[int, list[int], Array, Array]
"""Frontal key, parent keys, ``R`` and ``S`` (copies) of one conditional."""


class _ActiveCovariance:
    """Dense joint covariance of the active variables, each in its own slots of a square matrix.

    Variables are numbered ``0 .. n - 1`` with dimensions ``dims``.  Freed
    slots keep stale values and are reused first; the slots in use stay below
    ``high``, and are moved to the front when fewer than half of those are
    live, so that the row gathers stay about as wide as the active set.
    """

    def __init__(self, dims: NDArray[np.intp]) -> None:
        self.matrix = np.zeros((64, 64))
        width = int(dims.max(initial=1))
        self.table = np.full((dims.size, width), -1, dtype=np.intp)
        self.used = np.arange(width) < dims[:, None]
        self.free = list(range(63, -1, -1))
        self.live = np.zeros(64, dtype=bool)
        self.high = 0

    def index(self, ids: NDArray[np.intp]) -> NDArray[np.intp]:
        """Slots of variables ``ids``, concatenated in order."""
        return self.table[ids][self.used[ids]]

    def add(self, ids: NDArray[np.intp]) -> NDArray[np.intp]:
        """Reserve slots for variables ``ids`` (growing the matrix when full)."""
        used = self.used[ids]
        size = int(used.sum())
        if len(self.free) < size:
            old = self.matrix.shape[0]
            new = old + max(size, old // 2)
            grown = np.zeros((new, new))
            grown[:old, :old] = self.matrix
            self.matrix = grown
            self.live = np.concatenate([self.live, np.zeros(new - old, dtype=bool)])
            self.free = list(range(new - 1, old - 1, -1)) + self.free
        slots = np.array([self.free.pop() for _ in range(size)], dtype=np.intp)
        block = self.table[ids]
        block[used] = slots
        self.table[ids] = block
        self.live[slots] = True
        self.high = max(self.high, int(slots.max(initial=-1)) + 1)
        return slots

    def drop(self, ids: NDArray[np.intp]) -> None:
        """Release the slots of variables ``ids`` (compacting when few are live)."""
        slots = self.index(ids)
        self.live[slots] = False
        self.free.extend(slots.tolist())
        kept = np.flatnonzero(self.live[: self.high])
        if 2 * kept.size < self.high:
            self.matrix[: kept.size, : kept.size] = self.matrix[np.ix_(kept, kept)]
            moved = np.full(self.matrix.shape[0], -1, dtype=np.intp)
            moved[kept] = np.arange(kept.size)
            self.table = np.where(self.table >= 0, moved[self.table], -1)
            self.live[:] = False
            self.live[: kept.size] = True
            self.free = list(range(self.matrix.shape[0] - 1, kept.size - 1, -1))
            self.high = kept.size


def _unit(conditional: gtsam.GaussianConditional) -> tuple[Array, Array]:
    """Copies of ``R`` and ``S`` (all parents), after checking the noise is unit."""
    model = conditional.get_model()
    if model is not None and not np.array_equal(model.sigmas(), np.ones(model.dim())):
        raise ValueError(f"conditional with non-unit noise sigmas {model.sigmas()}")
    return np.array(conditional.R(), copy=True), np.array(conditional.S(), copy=True)


def _sequential(linear: gtsam.GaussianFactorGraph, ordering: gtsam.Ordering) -> list[Conditional]:
    """Conditionals of sequential elimination, last eliminated first."""
    bayes_net = linear.eliminateSequential(ordering)
    out = []
    for i in range(bayes_net.size() - 1, -1, -1):
        conditional = bayes_net.at(i)
        keys = list(conditional.keys())
        out.append((keys[0], keys[1:], *_unit(conditional)))
    return out


def _sweep(conditionals: Sequence[Conditional], groups: Sequence[Sequence[int]]) -> list[Array]:
    """Joint covariances of ``groups`` from conditionals listed parents first.

    Variable ``i`` is the frontal of conditional (sweep step) ``i``.
    """
    number = {key: i for i, (key, *_) in enumerate(conditionals)}
    dims = np.array([r.shape[0] for *_, r, _ in conditionals], dtype=np.intp)
    release = np.arange(len(conditionals))  # last step needing each variable
    parent_ids = []
    for step, (_, parents, _, _) in enumerate(conditionals):
        parent_ids.append(np.array([number[k] for k in parents], dtype=np.intp))
        release[parent_ids[-1]] = step  # steps increase: the last one stays
    group_ids = [np.array([number[k] for k in g], dtype=np.intp) for g in groups]
    due: dict[int, list[int]] = {}
    for g, ids in enumerate(group_ids):
        done = int(ids.max())
        due.setdefault(done, []).append(g)
        release[ids] = np.maximum(release[ids], done)
    order = np.argsort(release, kind="stable")
    bounds = np.searchsorted(release[order], np.arange(len(conditionals) + 1))

    active = _ActiveCovariance(dims)
    out: list[Array] = [np.zeros((0, 0))] * len(groups)
    for step, (_, _, r, s) in enumerate(conditionals):
        rows = active.index(parent_ids[step])
        inverse = lapack.dtrtri(r)[0]  # R is regular: GTSAM's elimination throws first
        gain = inverse @ s
        slots = active.add(np.array([step]))
        cross = -gain @ active.matrix[rows, : active.high]  # zero without parents
        active.matrix[slots, : active.high] = cross
        active.matrix[: active.high, slots] = cross.T
        active.matrix[np.ix_(slots, slots)] = inverse @ inverse.T - cross[:, rows] @ gain.T
        for g in due.get(step, ()):
            index = active.index(group_ids[g])
            out[g] = active.matrix[np.ix_(index, index)]
        active.drop(order[bounds[step] : bounds[step + 1]])
    return out


def sequential_marginals(
    linear: gtsam.GaussianFactorGraph,
    ordering: gtsam.Ordering,
    node_keys: Sequence[tuple[int, int]],
    offset_keys: Sequence[int],
) -> tuple[Array, Array]:
    """Joint covariances ``(n, 6, 6)`` of each node's ``(attitude, bias)`` keys (the attitude
    first, cross blocks included) and the variances ``(n_offsets,)`` of the 1-dimensional
    ``offset_keys`` (module docstring).

    ``ordering`` must hold every key of ``linear``; the separators (and so the
    cost) are those of that elimination order.  Raises ``ValueError`` for a
    constrained (non-unit-noise) conditional, GTSAM's ``RuntimeError`` for an
    indeterminate system.
    """
    groups = [list(pair) for pair in node_keys] + [[key] for key in offset_keys]
    joints = _sweep(_sequential(linear, ordering), groups)
    nodes = np.array(joints[: len(node_keys)]).reshape(len(node_keys), 6, 6)
    variances = np.array([c[0, 0] for c in joints[len(node_keys) :]])
    return nodes, variances
