"""The covariance ``mekf_paper`` reports: the filter's plus its input's, held over the
epochs the input misses (``attopt.experiments.adsb_snr.filters.considered_input_error``)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.filters import considered_input_error
from attopt.solvers.results import Track


def _track(valid, covariance, state_covariance=None):
    n = len(valid)
    quaternion = Rotation.from_rotvec(np.linspace(0, 0.1, 3 * n).reshape(n, 3)).as_quat()
    quaternion[~valid] = np.nan
    return Track(
        "t",
        quaternion,
        covariance,
        np.zeros(n),
        valid,
        np.where(valid, "", "no solution").astype(object),
        np.full(n, None, dtype=object),
        {},
        state_covariance=state_covariance,
        state=("attitude", "bias"),
    )


@settings(max_examples=30, deadline=None)
@given(st.lists(st.booleans(), min_size=1, max_size=12), st.integers(0, 2**32 - 1))
def test_the_latest_valid_input_covariance_is_added(source_valid, seed):
    rng = np.random.default_rng(seed)
    n = len(source_valid)
    valid = np.array(source_valid)
    factors = rng.normal(size=(n, 3, 3))
    source_covariance = factors @ factors.transpose(0, 2, 1)
    source = _track(valid, np.where(valid[:, None, None], source_covariance, np.nan))
    own = 1e-6 * np.tile(np.eye(3), (n, 1, 1))
    state = np.tile(np.eye(6), (n, 1, 1))
    track = _track(np.ones(n, dtype=bool), own, state)
    considered = considered_input_error(track, source)
    for k in range(n):
        earlier = np.flatnonzero(valid[: k + 1])
        added = source_covariance[earlier[-1]] if earlier.size else np.zeros((3, 3))
        np.testing.assert_allclose(considered.covariance[k], own[k] + added)
        np.testing.assert_allclose(considered.state_covariance[k][:3, :3], state[k][:3, :3] + added)
        np.testing.assert_array_equal(considered.state_covariance[k][3:, 3:], np.eye(3))
    np.testing.assert_array_equal(considered.quaternion, track.quaternion)
    np.testing.assert_array_equal(considered.valid, track.valid)
    np.testing.assert_array_equal(track.covariance, own)  # the input track is not changed


def test_a_track_the_filter_left_invalid_stays_nan():
    source = _track(np.ones(2, dtype=bool), np.tile(np.eye(3), (2, 1, 1)))
    covariance = np.stack([np.eye(3), np.full((3, 3), np.nan)])
    considered = considered_input_error(_track(np.array([True, False]), covariance), source)
    assert np.isnan(considered.covariance[1]).all()
    np.testing.assert_allclose(considered.covariance[0], 2 * np.eye(3))
