"""The views of a measurement's block labels (solvers/blocks.py) against their definitions."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from attopt.solvers.blocks import block_structure, count_blocks

LABELS = st.lists(st.integers(min_value=-3, max_value=6), min_size=1, max_size=30)


@given(LABELS)
def test_every_view_matches_its_definition(values: list[int]) -> None:
    labels = np.array(values, dtype=np.intp)
    blocks = block_structure(labels)
    ids = sorted(set(values))
    assert blocks.ids.tolist() == ids and count_blocks(labels) == len(ids)
    assert [ids[i] for i in blocks.index] == values
    seen = []
    for size, rows in blocks.layout:
        assert rows.shape[1] == size
        for block in rows:
            members = np.flatnonzero(labels == labels[block[0]])
            np.testing.assert_array_equal(block, members)
            seen.append(int(labels[block[0]]))
    assert sorted(seen) == ids
    assert [size for size, _ in blocks.layout] == sorted({values.count(i) for i in ids})
    members = blocks.members
    for row, label in enumerate(values):
        rows = np.flatnonzero(labels == label)
        np.testing.assert_array_equal(members.members[row][members.valid[row]], rows)
        assert rows[members.position[row]] == row
        np.testing.assert_array_equal(members.source[row][~members.valid[row]], 0)


def test_one_structure_per_layout_and_read_only() -> None:
    labels = np.array([2, 2, 5, 7, 7, 7])
    assert block_structure(labels) is block_structure(labels.copy())
    assert not block_structure(labels).ids.flags.writeable
    assert count_blocks(np.zeros(0, dtype=np.intp)) == 0
