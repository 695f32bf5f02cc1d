"""The filters' compiled gyro propagation against its numpy reference."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.gyro import MEMS_GYRO, SERIES_LIMIT
from attopt.formulations.kernels import INTERPRETED, KERNELS_ENV, compiled_loops, first_call
from attopt.solvers.filters import common, compiled, usque

# Rate scales (rad/s) over 0.1 s steps: angles below, at and far above the series limit.
SCALES = st.sampled_from([0.0, 1e-7, 0.5 * SERIES_LIMIT / 0.1, SERIES_LIMIT / 0.1, 0.05, 2.0])


def _draw(seed: int, scale: float, k: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    rates = rng.normal(size=(k, 3)) * scale
    dt = rng.uniform(0.02, 0.2, size=k)
    a = rng.normal(size=(6, 6))
    covariance = a @ a.T + 1e-3 * np.eye(6)
    noise = common.step_noise(MEMS_GYRO, dt, rng.uniform(0.0, 1e-8, size=k))
    return rates, dt, covariance, noise


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=SCALES, k=st.integers(0, 25))
def test_compiled_covariance_steps_equal_the_numpy_reference(
    seed: int, scale: float, k: int
) -> None:
    rates, dt, covariance, noise = _draw(seed, scale, k)
    p, total = compiled.covariance_steps(covariance, rates, dt, noise)
    p_ref, total_ref = common.covariance_steps(covariance, rates, dt, noise)
    np.testing.assert_allclose(p, p_ref, rtol=1e-12, atol=1e-12 * np.abs(p_ref).max())
    np.testing.assert_allclose(total, total_ref, rtol=1e-12, atol=1e-13)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=SCALES, k=st.integers(0, 25))
def test_compiled_quaternion_steps_equal_the_numpy_reference(
    seed: int, scale: float, k: int
) -> None:
    rng = np.random.default_rng(seed)
    quaternions = Rotation.random(13, rng=rng).as_quat()
    rates = rng.normal(size=(13, k, 3)) * scale
    dt = rng.uniform(0.02, 0.2, size=k)
    out = compiled.quaternion_steps(quaternions, rates, dt)
    np.testing.assert_allclose(out, common.quaternion_steps(quaternions, rates, dt), atol=1e-14)


def test_a_pass_of_steps_matches_scipy_and_the_closed_form_transition() -> None:
    """600 steps at a real rate: the attitude equals scipy's chain of increments, and the
    transitions' product the product of ``error_state_transition`` (independent code)."""
    rng = np.random.default_rng(3)
    rates = np.array([0.01, -0.02, 0.005]) + 1e-3 * rng.normal(size=(600, 3))
    dt = np.full(600, 0.1)
    start = Rotation.from_rotvec([0.3, -0.2, 1.0])
    expected = start
    for w in rates:
        expected = Rotation.from_rotvec(-w * 0.1) * expected
    out = compiled.quaternion_steps(start.as_quat()[None], rates[None], dt)[0]
    assert (Rotation.from_quat(out) * expected.inv()).magnitude() < 1e-12
    _, total = compiled.covariance_steps(np.eye(6), rates, dt, np.zeros((600, 6, 6)))
    from attopt.formulations.gyro import error_state_transition

    product = np.eye(6)
    for w in rates:
        product = error_state_transition(w, 0.1) @ product
    np.testing.assert_allclose(total, product, atol=1e-12)


@pytest.mark.parametrize("enabled", [True, False])
def test_the_dispatch_keeps_shapes_and_values(
    monkeypatch: pytest.MonkeyPatch, enabled: bool
) -> None:
    """``propagate_quaternion`` and ``propagate_covariance`` give the same values on either
    path, for one quaternion, a stack, rates shared by the stack, a scalar step and no
    steps."""
    monkeypatch.setattr(common, "compiled_loops", lambda: enabled)
    rng = np.random.default_rng(5)
    one, stack = Rotation.random(rng=rng).as_quat(), Rotation.random(4, rng=rng).as_quat()
    rates, own = 0.1 * rng.normal(size=(7, 3)), 0.1 * rng.normal(size=(4, 7, 3))
    dt = np.full(7, 0.1)
    cases = [(one, rates, dt), (one, rates, 0.1), (stack, own, dt), (stack, rates, dt)]
    cases.append((one, rates[:0], dt[:0]))
    for quaternion, r, step in cases:
        out = common.propagate_quaternion(quaternion, r, step)
        reference = common.quaternion_steps(quaternion, np.asarray(r), np.asarray(step))
        assert out.shape == np.shape(quaternion)
        np.testing.assert_allclose(out, reference, atol=1e-14)
    p, total = common.propagate_covariance(np.eye(6), rates, np.zeros(7), MEMS_GYRO, dt)
    p_ref, total_ref = common.covariance_steps(
        np.eye(6), rates, dt, common.step_noise(MEMS_GYRO, dt, np.zeros(7))
    )
    np.testing.assert_allclose(p, p_ref, rtol=1e-12)
    np.testing.assert_allclose(total, total_ref, rtol=1e-12, atol=1e-15)


def test_the_interpreted_setting_turns_the_compiled_path_off(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv(KERNELS_ENV, INTERPRETED)
    assert not compiled_loops.__wrapped__()
    monkeypatch.delenv(KERNELS_ENV)
    assert compiled_loops.__wrapped__()


def test_a_loops_compilation_is_printed_at_its_first_call_only(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``first_call`` reports a loop whose first call compiled it (a cache miss), once per
    label; the result is the loop's either way."""

    class Loop:
        stats = SimpleNamespace(cache_misses={"sig": 1}, cache_path="/cache")

        def __call__(self, x: float) -> float:
            return 2.0 * x

    label = "a test loop that compiles"
    assert first_call(Loop(), label, 1.5) == 3.0
    assert first_call(Loop(), label, 2.0) == 4.0
    printed = capsys.readouterr().err
    assert printed.count(f"attopt: compiled {label} in ") == 1 and "/cache" in printed


def test_the_loops_benchmark_prints_both_paths_and_their_agreement(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from attopt.experiments.benchmarks import propagation

    propagation.main(["--runs", "1", "--calls", "3", "--steps", "4"])
    lines = capsys.readouterr().out.splitlines()
    rows = [line for line in lines if line.startswith("| ") and "largest" not in line]
    assert [row.split(" | ")[0] for row in rows] == [
        "| MEKF prediction",
        "| USQUE prediction",
        "| gate, two vectors",
        "| vector innovation, 13 sigma points",
        "| MEKF update, two vectors",
        "| USQUE update, two vectors",
    ]
    assert all(float(row.split(" | ")[-1].rstrip(" |")) <= 1e-12 for row in rows)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=SCALES, k=st.integers(1, 25))
def test_compiled_unscented_prediction_equals_the_numpy_reference(
    seed: int, scale: float, k: int
) -> None:
    """USQUE's whole prediction: sigma points of a random covariance (up to tens of
    degrees), any rates and steps, the attitude, mean, covariance and deviations."""
    rates, dt, covariance, noise = _draw(seed, scale, k)
    rng = np.random.default_rng(seed)
    offsets, _ = usque.sigma_offsets(covariance * rng.uniform(1e-8, 0.3))
    arguments = (offsets, Rotation.random(rng=rng).as_quat(), 1e-3 * rng.normal(size=3))
    arguments += (rates, dt, noise)
    compiled_out = compiled.unscented_prediction(*arguments)
    for out, reference in zip(compiled_out, usque.unscented_prediction(*arguments), strict=True):
        np.testing.assert_allclose(out, reference, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("enabled", [True, False])
def test_usque_propagate_takes_either_path(monkeypatch: pytest.MonkeyPatch, enabled: bool) -> None:
    """``usque.propagate`` over ten steps from one state: the same prediction on the numpy
    and the compiled path, and the statistical transition only when asked for."""
    monkeypatch.setattr(usque, "compiled_loops", lambda: enabled)
    rng = np.random.default_rng(11)
    rates = np.radians([1.0, -2.0, 0.5]) + 1e-3 * rng.normal(size=(10, 3))
    gyro = SimpleNamespace(rates=rates, dt=np.full(10, 0.1), hold_variance=np.zeros(10))
    a = rng.normal(size=(6, 6))
    covariance = 1e-4 * (a @ a.T + np.eye(6))
    attitude, bias = Rotation.random(rng=rng), 1e-4 * rng.normal(size=3)
    out = usque.propagate(attitude, bias, covariance, gyro, slice(0, 10), MEMS_GYRO)
    noise = common.step_noise(MEMS_GYRO, gyro.dt, gyro.hold_variance)
    offsets, _ = usque.sigma_offsets(covariance)
    quaternion, mean, expected, _ = usque.unscented_prediction(
        offsets, attitude.as_quat(), bias, rates, gyro.dt, noise
    )
    assert (out[0] * Rotation.from_quat(quaternion).inv()).magnitude() < 1e-14
    np.testing.assert_allclose(out[1], bias + mean[3:], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(out[2], expected, rtol=1e-12, atol=1e-20)
    assert out[3].shape == (6, 6) and not out[4]
    lean = usque.propagate(attitude, bias, covariance, gyro, slice(0, 10), MEMS_GYRO, False)
    assert lean[3] is None
    np.testing.assert_array_equal(lean[2], out[2])
