"""The smoother's normal equations with transmitter offsets, eliminated in time order.

Variables: per node ``k`` the 6-vector ``[xi_k, d_k]`` (attitude and bias tangents,
:mod:`attopt.solvers.smoother.conventions`) and per transmitter ``j`` its offset
``o_j``.  The linearised cost ``1/2 ||A x - b||^2`` has the normal equations
``H x = g`` (``H = A^T A``, ``g = A^T b``) with the structure

* the gyro factors and the prior join consecutive nodes: ``H_kk``, ``H_k,k+1``;
* every SNR row joins its node's attitude and its transmitter's offset:
  ``H_k,o_j`` (``3 x 1`` per pair) and the offsets' diagonal;
* the offsets' priors are diagonal.

Elimination order: node 0, the offsets last seen at node 0, node 1, ... (a
sequential elimination in time order).  What node ``k`` leaves behind joins node
``k + 1`` and the *active* offsets (seen at or before ``k`` and again after it),
and it is held as one dense matrix over them.  Eliminating a node is then a
rank-6 update of it, eliminating the offsets whose transmitter has set a rank-``p``
update, so one elimination costs ``O(sum_k m_k^2)`` for ``m_k`` active offsets
(linear in the pass for a steady sky) and the conditionals take ``O(sum_k m_k)``
memory.  An offset no row touches (the optimiser's first step, before the
factors gain the offsets' columns) stays out of the active set.  GTSAM
eliminates the same ordering, but scatters its dense separator factors key by key
(one 1-dimensional key per offset) and builds one ``JacobianFactor`` per SNR row;
on the hour of ``adsb-snr`` (up to 1,752 active offsets) one elimination took
about 100 s there (``docs/smoother.md``), which is why it is done here.

Each elimination gives a conditional ``R x_F + S x_P = d`` (``R`` upper
triangular, unit noise); back substitution gives the solution
(:meth:`NormalEquations.solve`), and the backward sweep over the conditionals the
marginal covariances (:meth:`NormalEquations.marginals`; the Rauch-Tung-Striebel
recursion on a Bayes net, "selected inversion")::

    K = R^-1 S,   Cov(F, A) = -K Cov(P, A),   Cov(F) = R^-1 R^-T - Cov(F, P) K^T,

over the same active sets, at the same cost as the elimination.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from attopt.solvers.smoother.compiled import downdate
from attopt.solvers.smoother.conventions import Array, attitude_key, bias_key, offset_key

NODE = 6
"""Dimension of a node: the attitude's tangent ``xi`` then the bias's ``d``."""


class ActiveSet:
    """A dense symmetric matrix over the active offsets, the current node's block and
    its cross block to them, and a vector over both (the elimination's information or
    the sweep's covariance).

    The offsets sit in slots ``0 .. m - 1`` in activation order; removing some moves
    the last ones into their slots, so every update works on contiguous views.
    """

    def __init__(self, n_offsets: int) -> None:
        self.matrix = np.zeros((64, 64))
        self.vector = np.zeros(64)
        self.cross = np.zeros((NODE, 64))
        self.node = np.zeros((NODE, NODE))
        self.node_vector = np.zeros(NODE)
        self.ids = np.zeros(64, dtype=np.intp)
        self.slot = np.full(n_offsets, -1, dtype=np.intp)
        self.m = 0

    def add(self, ids: NDArray[np.intp]) -> slice:
        """Zeroed slots for offsets ``ids`` (growing the storage when full)."""
        m, p = self.m, ids.size
        if m + p > self.ids.size:
            size = max(m + p, 2 * self.ids.size)
            matrix = np.zeros((size, size))
            matrix[:m, :m] = self.matrix[:m, :m]
            self.matrix = matrix
            self.vector = np.concatenate([self.vector[:m], np.zeros(size - m)])
            self.cross = np.concatenate([self.cross[:, :m], np.zeros((NODE, size - m))], axis=1)
            self.ids = np.concatenate([self.ids[:m], np.zeros(size - m, dtype=np.intp)])
        new = slice(m, m + p)
        self.matrix[new, : m + p] = 0.0
        self.matrix[: m + p, new] = 0.0
        self.vector[new] = 0.0
        self.cross[:, new] = 0.0
        self.ids[new] = ids
        self.slot[ids] = np.arange(m, m + p)
        self.m = m + p
        return new

    def remove(self, slots: NDArray[np.intp]) -> None:
        """Release ``slots``, moving the last live slots into the freed ones below."""
        m = self.m - slots.size
        gone = np.zeros(self.m, dtype=bool)
        gone[slots] = True
        self.slot[self.ids[slots]] = -1
        holes = np.flatnonzero(gone[:m])
        movers = m + np.flatnonzero(~gone[m : self.m])
        if holes.size:
            self.matrix[holes, : self.m] = self.matrix[movers, : self.m]
            self.matrix[: self.m, holes] = self.matrix[: self.m, movers]  # (holes, holes) too
            self.vector[holes] = self.vector[movers]
            self.cross[:, holes] = self.cross[:, movers]
            self.ids[holes] = self.ids[movers]
            self.slot[self.ids[holes]] = holes
        self.m = m

    @property
    def live(self) -> tuple[Array, Array, Array]:
        """Views of the live block, vector and cross block."""
        m = self.m
        return self.matrix[:m, :m], self.vector[:m], self.cross[:, :m]


@dataclass(frozen=True)
class Conditional:
    """``R x_F + S_node x_node + S_offsets o_parents = d`` (module docstring), with
    ``R^-1`` (upper triangular) kept rather than ``R``.

    ``node`` is the frontal node (``offsets`` empty) or ``-1`` for frontal
    ``offsets``; ``parent`` the parent node or ``-1``; ``parents`` the parent
    offsets, in the order of ``s_offsets``' columns.
    """

    node: int
    offsets: NDArray[np.intp]
    parent: int
    parents: NDArray[np.intp]
    r_inverse: Array
    s_node: Array
    s_offsets: Array
    d: Array


@dataclass(frozen=True)
class Solution:
    """``x`` of the normal equations: ``(n, 6)`` node tangents ``[xi, d]`` and the offsets."""

    nodes: Array
    offsets: Array


@dataclass
class NormalEquations:
    """``H x = g`` of the smoother with offsets, by blocks (module docstring).

    Attributes:
        node: ``(n, 6, 6)`` ``H_kk``.
        chain: ``(n - 1, 6, 6)`` ``H_k,k+1``.
        node_gradient: ``(n, 6)``.
        offset: ``(N,)`` the offsets' diagonal of ``H``.
        offset_gradient: ``(N,)``.
        seen: per node the offsets its rows touch (unique).
        cross: per node ``(3, p_k)``: ``H`` between its attitude and ``seen``.
    """

    node: Array
    chain: Array
    node_gradient: Array
    offset: Array
    offset_gradient: Array
    seen: list[NDArray[np.intp]]
    cross: list[Array]

    @classmethod
    def empty(cls, n: int, n_offsets: int) -> NormalEquations:
        none = np.zeros(0, dtype=np.intp)
        return cls(
            node=np.zeros((n, NODE, NODE)),
            chain=np.zeros((max(n - 1, 0), NODE, NODE)),
            node_gradient=np.zeros((n, NODE)),
            offset=np.zeros(n_offsets),
            offset_gradient=np.zeros(n_offsets),
            seen=[none] * n,
            cross=[np.zeros((3, 0))] * n,
        )

    def add_linear(
        self, linear: gtsam.GaussianFactorGraph, keys: dict[int, tuple[int, int]]
    ) -> None:
        """Add GTSAM's linearised factors (``augmentedInformation`` of each).

        ``keys`` maps a key to ``(node, 0 or 3)`` for an attitude or bias key and
        to ``(-1 - j, 0)`` for offset ``j``.  Raises ``ValueError`` for a factor
        outside the structure (a node joined to another than its neighbour, an
        offset joined to anything).
        """
        for i in range(linear.size()):
            factor = linear.at(i)
            where = [keys[key] for key in factor.keys()]
            dims = [1 if node < 0 else 3 for node, _ in where]
            starts = np.concatenate([[0], np.cumsum(dims)])
            info = factor.augmentedInformation()
            gradient = info[:-1, -1]
            for a, (node_a, at_a) in enumerate(where):
                rows = slice(starts[a], starts[a + 1])
                if node_a < 0:
                    if len(where) > 1:
                        raise ValueError("a built-in factor joins an offset to another variable")
                    self.offset[-1 - node_a] += info[0, 0]
                    self.offset_gradient[-1 - node_a] += gradient[0]
                    continue
                self.node_gradient[node_a, at_a : at_a + 3] += gradient[rows]
                for b, (node_b, at_b) in enumerate(where):
                    block = info[rows, starts[b] : starts[b + 1]]
                    if node_b == node_a:
                        self.node[node_a, at_a : at_a + 3, at_b : at_b + 3] += block
                    elif node_b == node_a + 1:
                        self.chain[node_a, at_a : at_a + 3, at_b : at_b + 3] += block
                    elif node_b != node_a - 1:
                        raise ValueError(f"a factor joins nodes {node_a} and {node_b}")

    def add_rows(self, k: int, system: Array, column: Array | None, ids: NDArray[np.intp]) -> None:
        """Add node ``k``'s whitened rows ``[a | b]`` ``(m, 4)`` (attitude Jacobian and
        right-hand side), with ``column`` ``(m,)`` each row's coefficient of its own
        offset ``ids`` ``(m,)`` (``None``: no offset column yet)."""
        a, b = system[:, :3], system[:, 3]
        self.node[k, :3, :3] += a.T @ a
        self.node_gradient[k, :3] += a.T @ b
        if column is None or not ids.size:
            return
        seen, index = np.unique(ids, return_inverse=True)
        p = seen.size
        self.offset[seen] += np.bincount(index, column * column, p)
        self.offset_gradient[seen] += np.bincount(index, column * b, p)
        weighted = a * column[:, None]
        self.seen[k] = seen
        self.cross[k] = np.stack([np.bincount(index, weighted[:, i], p) for i in range(3)])

    def predicted_decrease(self, x: Solution, damping: float) -> float:
        """``g.x - x.H.x / 2`` of the undamped model at the solution ``x`` of the damped
        equations ``(H + damping I) x = g``: ``(g.x + damping |x|^2) / 2``."""
        gx = float(np.sum(self.node_gradient * x.nodes) + self.offset_gradient @ x.offsets)
        squared = float(np.sum(x.nodes**2) + x.offsets @ x.offsets)
        return 0.5 * (gx + damping * squared)

    def _spans(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        return offset_spans(self.seen, self.offset.size)

    def eliminate(self, damping: float = 0.0) -> tuple[list[Conditional], NDArray[np.intp]]:
        """The conditionals of ``H + damping I`` in elimination order, and the offsets no
        row touches (each its own prior: ``H_jj`` alone).

        Raises ``np.linalg.LinAlgError`` when a pivot block is not positive definite.
        """
        n = self.node.shape[0]
        first, last = self._spans()
        rising, setting = _by_node(first, n), _by_node(last, n)
        active = ActiveSet(self.offset.size)
        eye = damping * np.eye(NODE)
        out: list[Conditional] = []
        none = np.zeros(0, dtype=np.intp)
        for k in range(n):
            new = active.add(rising[k])
            active.matrix[new, new] = np.diag(self.offset[rising[k]] + damping)
            active.vector[new] = self.offset_gradient[rising[k]]
            active.node += self.node[k] + eye
            active.node_vector += self.node_gradient[k]
            active.cross[:3, active.slot[self.seen[k]]] += self.cross[k]
            matrix, vector, cross = active.live
            inverse = _pivot(active.node)
            s_offsets = inverse @ cross
            d = inverse @ active.node_vector
            vector -= s_offsets.T @ d
            if k + 1 < n:
                s_node = inverse @ self.chain[k]
                active.node = -s_node.T @ s_node
                active.node_vector = -s_node.T @ d
                cross[:] = -s_node.T @ s_offsets
            else:
                s_node = np.zeros((NODE, 0))
            parents = active.ids[: active.m].copy()
            out.append(
                Conditional(
                    k, none, k + 1 if k + 1 < n else -1, parents, inverse.T, s_node, s_offsets, d
                )
            )
            update = s_offsets  # the block's rank-6 update, made once with the offsets'
            if setting[k].size:
                slots = active.slot[setting[k]]
                rows = matrix[slots] - s_offsets[:, slots].T @ s_offsets
                conditional, s_setting = self._eliminate_offsets(
                    active, slots, rows, k + 1 < n, k + 1
                )
                out.append(conditional)
                update = np.vstack([s_offsets, s_setting])
            downdate(active.matrix, update)  # matrix -= update^T update
            if setting[k].size:
                active.remove(slots)
        isolated = np.flatnonzero(last < 0)
        return out, isolated

    @staticmethod
    def _eliminate_offsets(
        active: ActiveSet, slots: NDArray[np.intp], rows: Array, node: bool, k: int
    ) -> tuple[Conditional, Array]:
        """Eliminate the offsets in ``slots`` (their transmitters have set), whose rows of the
        active block are ``rows`` (``(p, m)``, the last node's update made): their
        conditional, and ``S`` ``(p, m)``, whose ``S^T S`` the caller takes from the block
        before removing them (with the node's, in one update)."""
        _, vector, cross = active.live
        inverse = _pivot(rows[:, slots])
        s_offsets = inverse @ rows
        d = inverse @ vector[slots]
        vector -= s_offsets.T @ d
        s_node = np.zeros((slots.size, 0))
        if node:
            s_node = inverse @ cross[:, slots].T
            active.node -= s_node.T @ s_node
            active.node_vector -= s_node.T @ d
            cross -= s_node.T @ s_offsets
        keep = np.ones(active.m, dtype=bool)
        keep[slots] = False
        parents = active.ids[: active.m][keep]
        ids = active.ids[slots].copy()
        conditional = Conditional(
            -1, ids, k if node else -1, parents, inverse.T, s_node, s_offsets[:, keep], d
        )
        return conditional, s_offsets

    def solve(self, damping: float = 0.0) -> Solution:
        """``x`` of ``(H + damping I) x = g`` by elimination and back substitution."""
        conditionals, isolated = self.eliminate(damping)
        nodes = np.zeros((self.node.shape[0], NODE))
        offsets = np.zeros(self.offset.size)
        offsets[isolated] = self.offset_gradient[isolated] / (self.offset[isolated] + damping)
        for c in reversed(conditionals):
            rhs = c.d - c.s_offsets @ offsets[c.parents]
            if c.parent >= 0:
                rhs = rhs - c.s_node @ nodes[c.parent]
            x = c.r_inverse @ rhs
            if c.node >= 0:
                nodes[c.node] = x
            else:
                offsets[c.offsets] = x
        return Solution(nodes, offsets)

    def marginals(self) -> tuple[Array, Array]:
        """Marginal covariances ``(n, 6, 6)`` of the nodes' ``[xi, d]`` and the offsets'
        variances ``(N,)`` of ``H^-1`` (module docstring)."""
        conditionals, isolated = self.eliminate()
        n = self.node.shape[0]
        first, _ = self._spans()
        rising = _by_node(first, n)
        nodes = np.zeros((n, NODE, NODE))
        variances = np.zeros(self.offset.size)
        variances[isolated] = 1.0 / self.offset[isolated]
        active = ActiveSet(self.offset.size)  # its node: the parent of the next node
        for c in reversed(conditionals):
            inverse = c.r_inverse
            gain_node = inverse @ c.s_node if c.parent >= 0 else None
            gain = np.zeros((inverse.shape[0], active.m))
            gain[:, active.slot[c.parents]] = inverse @ c.s_offsets
            matrix, _, cross = active.live
            with_offsets = -gain @ matrix
            with_node = -gain @ cross.T
            if gain_node is not None:
                with_offsets -= gain_node @ cross
                with_node -= gain_node @ active.node
            own = inverse @ inverse.T - with_offsets @ gain.T
            if gain_node is not None:
                own -= with_node @ gain_node.T
            if c.node >= 0:
                nodes[c.node] = own
                active.node, active.cross[:, : active.m] = own, with_offsets
                active.remove(active.slot[rising[c.node]])
            else:
                variances[c.offsets] = np.diagonal(own)
                slots = active.add(c.offsets)
                m = active.m
                active.matrix[slots, : m - c.offsets.size] = with_offsets
                active.matrix[: m - c.offsets.size, slots] = with_offsets.T
                active.matrix[slots, slots] = own
                active.cross[:, slots] = with_node.T
        return nodes, variances


def offset_spans(
    seen: Sequence[NDArray[np.intp]], n_offsets: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Each offset's first and last node (``-1`` for an offset no row touches) from the
    offsets ``seen`` at each node."""
    first = np.full(n_offsets, len(seen), dtype=np.intp)
    last = np.full(n_offsets, -1, dtype=np.intp)
    for k, ids in enumerate(seen):
        first[ids] = np.minimum(first[ids], k)
        last[ids] = k
    first[last < 0] = -1
    return first, last


def active_counts(seen: Sequence[NDArray[np.intp]], n_offsets: int) -> NDArray[np.intp]:
    """Per node, the offsets active when it is eliminated (seen at or before it and at or
    after it; ``seen`` as in :func:`offset_spans`): its pivot's dense block is ``6 +``
    this, and one elimination costs ``O(sum of its squares)`` (module docstring)."""
    first, last = offset_spans(seen, n_offsets)
    touched = last >= 0
    change = np.zeros(len(seen) + 1, dtype=np.intp)
    np.add.at(change, first[touched], 1)
    np.add.at(change, last[touched] + 1, -1)
    return np.cumsum(change)[:-1]


def _pivot(block: Array) -> Array:
    """``L^-1`` of the lower Cholesky factor ``L = R^T`` of a pivot block (LAPACK
    ``dtrtri``: the blocks are small, and ``scipy.linalg.solve_triangular``'s checks
    cost more than the solves).  Raises ``np.linalg.LinAlgError`` when the block is
    not positive definite."""
    inverse, info = lapack.dtrtri(np.linalg.cholesky(block), lower=1)
    if info:
        raise np.linalg.LinAlgError(f"singular pivot (dtrtri info {info})")
    return inverse


def _by_node(node: NDArray[np.intp], n: int) -> list[NDArray[np.intp]]:
    """For each node ``0 .. n - 1`` the indices ``j`` with ``node[j]`` equal to it."""
    order = np.argsort(node, kind="stable")
    bounds = np.searchsorted(node[order], np.arange(n + 1))
    return [order[bounds[k] : bounds[k + 1]] for k in range(n)]


@lru_cache(maxsize=8)
def structure_keys(n: int, n_offsets: int) -> dict[int, tuple[int, int]]:
    """The ``keys`` map of :meth:`NormalEquations.add_linear` for ``n`` nodes and
    ``n_offsets`` offsets (shared, not to be modified)."""
    out = {attitude_key(k): (k, 0) for k in range(n)}
    out.update({bias_key(k): (k, 3) for k in range(n)})
    out.update({offset_key(j): (-1 - j, 0) for j in range(n_offsets)})
    return out
