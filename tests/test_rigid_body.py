"""Euler's equation with wheels (Yang et al. 2014 eq. 23): numpy and CasADi agree, and the
torque-free motion keeps the angular momentum's magnitude and the kinetic energy."""

from __future__ import annotations

import casadi as ca
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from attopt.formulations.rigid_body import YANG2014_INERTIA, angular_acceleration

VECTORS = arrays(np.float64, 3, elements=st.floats(-1.0, 1.0))


@settings(max_examples=50, deadline=None)
@given(omega=VECTORS, wheel=VECTORS)
def test_numpy_and_casadi_agree_and_conserve(omega, wheel):
    numeric = angular_acceleration(omega, wheel, YANG2014_INERTIA)
    symbol = ca.SX.sym("omega", 3)
    function = ca.Function(
        "f", [symbol], [angular_acceleration(symbol, ca.DM(wheel), YANG2014_INERTIA)]
    )
    np.testing.assert_allclose(function(omega).full().ravel(), numeric, rtol=1e-12, atol=1e-15)
    momentum = YANG2014_INERTIA @ omega + wheel
    torque = YANG2014_INERTIA @ numeric  # = -omega x momentum
    scale = np.linalg.norm(momentum) ** 2 * np.linalg.norm(omega) + 1e-3
    assert abs(momentum @ torque) <= 1e-12 * scale  # |H| constant
    assert abs(omega @ torque) <= 1e-12 * scale  # kinetic energy constant (wheels fixed)


def test_batched_rates_match_one_at_a_time():
    rng = np.random.default_rng(3)
    omega, wheel = rng.standard_normal((5, 3)), rng.standard_normal((5, 3))
    batch = angular_acceleration(omega, wheel, YANG2014_INERTIA)
    for k in range(5):
        np.testing.assert_allclose(
            batch[k], angular_acceleration(omega[k], wheel[k], YANG2014_INERTIA), rtol=1e-14
        )
