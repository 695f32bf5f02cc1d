"""The filters' numpy quaternion algebra equals scipy's ``Rotation`` to round-off, and the
closed-form error Jacobian equals CasADi's derivative of the increment it inverts."""

from __future__ import annotations

import casadi as ca
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations import quaternion_algebra as qa
from attopt.formulations.attitude_model import increment_matrix
from attopt.solvers.filters.common import (
    apply_error,
    error_jacobian,
    error_vector,
    propagate_attitude,
)
from tests.strategies import attitudes

ROUND_OFF = 1e-15
"""Largest difference from scipy of a quaternion component or an MRP (a few ulps)."""

vectors = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)
short_errors = st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3).map(np.array)
"""Error vectors of norm below 4 (MRPs inside the unit ball: angles below 180 deg)."""
scales = st.sampled_from([0.0, 1e-12, 1e-7, 1e-3, 1.0])


@given(attitudes(), attitudes())
def test_compose_is_scipy_product(p: Rotation, q: Rotation) -> None:
    np.testing.assert_allclose(
        qa.compose(p.as_quat(), q.as_quat()), (p * q).as_quat(), rtol=0, atol=4 * ROUND_OFF
    )


@given(attitudes())
def test_conjugate_is_scipy_inverse(q: Rotation) -> None:
    np.testing.assert_array_equal(qa.conjugate(q.as_quat()), q.inv().as_quat())


@given(vectors, scales)
def test_from_rotation_vector_is_scipy(v: np.ndarray, scale: float) -> None:
    np.testing.assert_allclose(
        qa.from_rotation_vector(scale * v),
        Rotation.from_rotvec(scale * v).as_quat(),
        rtol=0,
        atol=4 * ROUND_OFF,
    )


@given(vectors, scales)
def test_mrp_conversions_are_scipy(p: np.ndarray, scale: float) -> None:
    rotation = Rotation.from_mrp(scale * p)
    np.testing.assert_allclose(qa.from_mrp(scale * p), rotation.as_quat(), rtol=0, atol=ROUND_OFF)
    # as_mrp is the MRP of the shorter rotation, whichever sign the quaternion has
    for sign in (1.0, -1.0):
        np.testing.assert_allclose(
            qa.to_mrp(sign * rotation.as_quat()), rotation.as_mrp(), rtol=0, atol=4 * ROUND_OFF
        )


def test_stacks_broadcast_against_one_quaternion() -> None:
    stack = Rotation.random(7, random_state=3)
    one = Rotation.random(random_state=4)
    np.testing.assert_allclose(
        qa.compose(stack.as_quat(), one.as_quat()), (stack * one).as_quat(), atol=4 * ROUND_OFF
    )
    np.testing.assert_allclose(
        error_vector(stack, one), 4.0 * (stack * one.inv()).as_mrp(), atol=8 * ROUND_OFF
    )


@given(attitudes(), short_errors)
def test_error_vector_inverts_apply_error(reference: Rotation, delta: np.ndarray) -> None:
    """``apply_error`` is ``Rotation.from_mrp(delta / 4) * reference`` and ``error_vector``
    takes it back."""
    perturbed = apply_error(delta, reference)
    expected = Rotation.from_mrp(delta / 4.0) * reference
    assert (perturbed * expected.inv()).magnitude() < 1e-14
    np.testing.assert_allclose(error_vector(perturbed, reference), delta, atol=1e-13)


def _ad_error_jacobian() -> ca.Function:
    """CasADi AD of the body-frame perturbation of ``C(x + d) C(x)^T`` in ``d`` at 0."""
    x, dx = ca.SX.sym("x", 3), ca.SX.sym("dx", 3)
    turn = increment_matrix(x + dx) @ increment_matrix(x).T
    body = ca.vertcat(turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1])
    jacobian = ca.substitute(ca.jacobian(0.5 * body, dx), dx, ca.DM.zeros(3))
    return ca.Function("error_jacobian", [x], [jacobian])


@settings(max_examples=50)
@given(vectors)
def test_error_jacobian_is_ad_of_the_increment(delta: np.ndarray) -> None:
    np.testing.assert_allclose(
        error_jacobian(delta), _ad_error_jacobian()(delta).full(), rtol=0, atol=1e-14
    )


def test_error_jacobian_is_identity_at_zero() -> None:
    np.testing.assert_array_equal(error_jacobian(np.zeros(3)), np.eye(3))


def test_propagate_attitude_is_the_product_of_scipy_increments() -> None:
    """One attitude and a stack, over steps of one length or several: the increments
    ``exp(-[w x] dt)`` applied in order, later steps on the left."""
    rng = np.random.default_rng(5)
    rates = 0.3 * rng.standard_normal((4, 6, 3))
    attitude = Rotation.random(4, random_state=6)
    for dt in (0.1, np.linspace(0.05, 0.3, 6)):
        steps = np.broadcast_to(np.asarray(dt)[..., None], rates.shape)
        expected = attitude
        for j in range(rates.shape[1]):
            expected = Rotation.from_rotvec(-rates[:, j] * steps[:, j]) * expected
        stack = propagate_attitude(attitude, rates, dt)
        assert np.max((stack * expected.inv()).magnitude()) < 1e-14
        one = propagate_attitude(attitude[1], rates[1], dt)
        assert one.single and (one * expected[1].inv()).magnitude() < 1e-14
    assert propagate_attitude(attitude, rates[:, :0], 0.1) is attitude
