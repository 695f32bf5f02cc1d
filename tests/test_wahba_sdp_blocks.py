"""The SDP's blocks (:attr:`~attopt.solvers.wahba.sdp.SdpOptions.block_size`) against one
solve per epoch, with its certificate per epoch."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.experiments.benchmarks.wahba import _problems
from attopt.formulations.conventions import attitude_error
from attopt.formulations.wahba_sdp import BlockSolution, WahbaSDP
from attopt.solvers.wahba import Q_METHOD, SDP
from attopt.solvers.wahba.sdp import SdpOptions


def angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angles between rows of scalar-last quaternions."""
    return np.linalg.norm(attitude_error(Rotation.from_quat(a), Rotation.from_quat(b)), axis=1)


def sdp(block_size: int):
    return replace(SDP, options=SdpOptions(block_size=block_size))


def test_sdp_blocks_agree_with_one_solve_per_epoch():
    """37 benchmark epochs in blocks of 8 (the last one padded) give the per-epoch answers
    and certificates."""
    body, reference, weights, _ = _problems(37, seed=3)
    blocks = sdp(8).solve_batch(body, reference, weights)
    single = sdp(1).solve_batch(body, reference, weights)
    assert blocks.valid.all() and single.valid.all()
    assert angles(blocks.quaternion, single.quaternion).max() < 1e-8
    assert np.nanmax(blocks.diagnostics["duality_gap"]) < 1e-8
    assert np.nanmax(blocks.diagnostics["rank_one_ratio"]) < 1e-6
    np.testing.assert_allclose(
        blocks.diagnostics["sdp_value"], single.diagnostics["sdp_value"], rtol=1e-8
    )
    exact = Q_METHOD.solve_batch(body, reference, weights)
    assert angles(blocks.quaternion, exact.quaternion).max() < 1e-8


def test_sdp_flags_a_degenerate_epoch_inside_a_block_and_keeps_its_neighbours():
    """A repeated lambda_max (``B = diag(1, 1, -1)``) at epoch 4 of a block: ``X`` is not
    rank one there, and only there."""
    rng = np.random.default_rng(0)
    truth = Rotation.random(10, random_state=1)
    reference = rng.normal(size=(10, 3, 3))
    reference /= np.linalg.norm(reference, axis=-1, keepdims=True)
    body = np.stack([truth[i].apply(reference[i]) for i in range(10)])
    body[4], reference[4] = np.eye(3), np.diag([1.0, 1.0, -1.0])
    track = sdp(8).solve_batch(body, reference, np.ones((10, 3)))
    assert track.valid.tolist() == [i != 4 for i in range(10)]
    assert "not rank one" in track.reason[4]
    keep = track.valid
    assert angles(track.quaternion[keep], truth[keep].as_quat()).max() < 1e-8


def test_sdp_block_whose_solve_fails_is_solved_epoch_by_epoch(monkeypatch):
    body, reference, weights, _ = _problems(10, seed=4)

    solve_blocks = WahbaSDP.solve_blocks

    def failing(self, k, solver, **options):
        if self.size == 1:  # the one-epoch problem still works
            return solve_blocks(self, k, solver, **options)
        nan = np.full(self.size, np.nan)
        return BlockSolution(np.full((self.size, 4, 4), np.nan), nan, nan, "solver_error")

    monkeypatch.setattr(WahbaSDP, "solve_blocks", failing)
    track = sdp(4).solve_batch(body, reference, weights)
    assert track.valid.all()
    assert (
        angles(track.quaternion, Q_METHOD.solve_batch(body, reference, weights).quaternion).max()
        < 1e-8
    )


def test_sdp_block_size_is_validated():
    with pytest.raises(ValueError, match="block_size"):
        SdpOptions(block_size=0)
    with pytest.raises(ValueError, match="one epoch"):
        WahbaSDP(2).solve(np.eye(4))
