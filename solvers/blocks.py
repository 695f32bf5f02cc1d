"""The blocks of a measurement's rows: rows with the same label are one block (a unit
vector's three components, one DOA's two angles), correlated within it and independent of
the other blocks (:attr:`~attopt.formulations.attitude_measurement.AttitudeMeasurement.blocks`).

The filters' gate tests each block's normalised innovation
(:func:`~attopt.solvers.filters.common.block_nis`), the updates count the blocks they use
or gate, and the smoother differentiates each block's innovation
(:func:`~attopt.solvers.smoother.measurement_factors.innovation_jacobian`); each needs
another view of the same labels.  A pass's epochs repeat a few layouts, so
:func:`block_structure` computes the views once per layout (cached by the labels'
bytes) and each view on first use.

Example::

    >>> import numpy as np
    >>> blocks = block_structure(np.array([4, 4, 4, 9, 9]))
    >>> blocks.ids.tolist(), blocks.index.tolist()
    ([4, 9], [0, 0, 0, 1, 1])
    >>> [(size, rows.tolist()) for size, rows in blocks.layout]
    [(2, [[3, 4]]), (3, [[0, 1, 2]])]
    >>> blocks.members.position.tolist()
    [0, 1, 2, 0, 1]
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class BlockMembers:
    """Where each row sits in its block (:attr:`BlockStructure.members`).

    Attributes:
        members: ``(m, s)``, for each row the rows of its block in order (``-1``
            padding), ``s`` the largest block size.
        position: ``(m,)`` each row's position in its block.
        valid: ``(m, s)`` where ``members`` is a row.
        source: ``(m, s)`` ``members`` with the padding at row 0 (safe to index with).
    """

    members: NDArray[np.intp]
    position: NDArray[np.intp]
    valid: NDArray[np.bool_]
    source: NDArray[np.intp]


class BlockStructure:
    """The views of one layout of block labels (module docstring).  Its arrays are
    shared between the epochs of that layout, not to be modified."""

    def __init__(self, labels: NDArray[np.intp]) -> None:
        self.labels = labels

    @cached_property
    def _unique(self) -> tuple[NDArray[np.intp], ...]:
        """``np.unique``'s labels, first rows, inverse and counts."""
        unique = np.unique(self.labels, return_index=True, return_inverse=True, return_counts=True)
        for array in unique:
            array.flags.writeable = False
        return unique

    @property
    def ids(self) -> NDArray[np.intp]:
        """The distinct labels, in increasing order."""
        return self._unique[0]

    @property
    def index(self) -> NDArray[np.intp]:
        """``(m,)`` each row's index in :attr:`ids` (``np.unique``'s inverse)."""
        return self._unique[2]

    @property
    def count(self) -> int:
        """The number of blocks."""
        return int(self.ids.size)

    @cached_property
    def layout(self) -> tuple[tuple[int, NDArray[np.intp]], ...]:
        """The rows of each block by block size: ``(size, rows)`` with ``rows`` ``(blocks
        of that size, size)``, the sizes increasing, so that blocks of one size are
        handled together."""
        ids, first, _, sizes = self._unique
        layout = []
        for size in np.unique(sizes):
            members = ids[sizes == size]
            rows = (
                np.stack([np.flatnonzero(self.labels == b) for b in members])
                if size > 1
                else first[sizes == size][:, None]
            )
            layout.append((int(size), rows))
        return tuple(layout)

    @cached_property
    def members(self) -> BlockMembers:
        """Where each row sits in its block (:class:`BlockMembers`)."""
        _, _, inverse, sizes = self._unique
        order = np.argsort(inverse, kind="stable")
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        width = int(sizes.max()) if sizes.size else 0
        members = np.full((sizes.size, width), -1, dtype=np.intp)
        position = np.arange(self.labels.size) - np.repeat(starts, sizes)
        members[np.repeat(np.arange(sizes.size), sizes), position] = order
        members = members[inverse]
        positions = np.zeros(self.labels.size, dtype=np.intp)
        positions[order] = position
        valid = members >= 0
        return BlockMembers(members, positions, valid, np.where(valid, members, 0))


def block_structure(labels: NDArray[np.intp]) -> BlockStructure:
    """The :class:`BlockStructure` of the block labels ``labels`` ``(m,)``, one per layout
    (module docstring)."""
    return _block_structure(np.ascontiguousarray(labels, dtype=np.intp).tobytes())


@lru_cache(maxsize=1024)
def _block_structure(labels: bytes) -> BlockStructure:
    array = np.frombuffer(labels, dtype=np.intp)
    return BlockStructure(array)


def count_blocks(labels: NDArray[np.intp]) -> int:
    """The number of distinct block labels in ``labels``."""
    return 0 if labels.size == 0 else block_structure(labels).count
