"""Compiled measurement kernels (``formulations/kernels.py``): equal to CasADi's interpreter
to 1e-13 relative on every measurement type, evaluated in blocks, built once per machine and
falling back to the interpreter without a compiler."""

from __future__ import annotations

import logging

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations import kernels
from attopt.formulations.doa_array import YANG2014_UCA
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.kernels import BLOCK, evaluate_mapped, kernel
from attopt.formulations.passes import Pass
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.doa.music import spectrum_function
from tests.contract_cases import CASES

needs_compiler = pytest.mark.skipif(kernels.compiler() is None, reason="no C compiler here")

RTOL = 1e-13
"""Stated tolerance between compiled and interpreted kernels (relative to each output's
largest magnitude)."""


@pytest.fixture(autouse=True)
def compiled_by_default(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test starts in the default mode, whatever ``ATTOPT_KERNELS`` the run has."""
    monkeypatch.delenv(kernels.KERNELS_ENV, raising=False)


def _assert_equal_to_round_off(compiled: np.ndarray, interpreted: np.ndarray) -> None:
    scale = np.nanmax(np.abs(interpreted), initial=1.0)
    np.testing.assert_allclose(compiled, interpreted, rtol=RTOL, atol=RTOL * scale)
    assert np.array_equal(np.isnan(compiled), np.isnan(interpreted))


def _symbolic_models(seed: int) -> list:
    """The symbolic models of every measurement of the first epochs of every contract case
    (and of the other types the cases test refusal with)."""
    models = {}
    problems = [
        p for case in CASES.values() for p in (case.draw(seed, True).problem, case.foreign(seed))
    ]
    for problem in problems:
        snapshots = problem.snapshots[:3] if isinstance(problem, Pass) else [problem]
        for snapshot in snapshots:
            for measurement in snapshot.measurements:
                model = measurement.symbolic_model()
                models.setdefault(model.structure, (model, measurement.z))
                if isinstance(measurement, SnrMeasurement):
                    truncated = SnrMeasurement(measurement.epoch, truncated=True)
                    models.setdefault(
                        truncated.symbolic_model().structure,
                        (truncated.symbolic_model(), truncated.z),
                    )
    for measurement in _doa_measurements():
        models.setdefault(
            measurement.symbolic_model().structure, (measurement.symbolic_model(), measurement.z)
        )
    return list(models.values())


def _doa_measurements() -> list[DoaMeasurement]:
    """DOAs of two stations, one off the array axis and one near it (direction cosines)."""
    stations = np.array([[300.0, 100.0, 800.0], [0.0, 1e-4, 900.0]])
    covariance = np.tile(1e-6 * np.eye(2), (2, 1, 1))
    doas = np.array([[0.4, 0.3], [1e-7, 2.0]])
    return [
        DoaMeasurement(doas[:1], covariance[:1], stations[:1]),
        DoaMeasurement(doas, covariance, stations),
    ]


@pytest.fixture(scope="module")
def models() -> list:
    return _symbolic_models(3)


def test_every_measurement_type_is_covered(models: list) -> None:
    names = {model.model.__name__ for model, _ in models}
    assert {
        "body_vectors_model",
        "euler321_model",
        "doa_model",
        "snr_model",
        "truncated_snr",
    } <= names
    assert len(models) >= 6


@needs_compiler
def test_compiled_kernels_equal_the_interpreter(
    models: list, monkeypatch: pytest.MonkeyPatch
) -> None:
    attitudes = Rotation.random(37, random_state=np.random.default_rng(5))
    for model, z in models:
        assert kernel(model.function).class_name() == "External", model.model.__name__
        compiled = model.evaluate(attitudes)
        compiled_nu = model.innovation_values(z, compiled[0])
        with monkeypatch.context() as patch:
            patch.setenv(kernels.KERNELS_ENV, kernels.INTERPRETED)
            assert kernel(model.function) is model.function
            interpreted = model.evaluate(attitudes)
            interpreted_nu = model.innovation_values(z, interpreted[0])
        for a, b in zip((*compiled, compiled_nu), (*interpreted, interpreted_nu), strict=True):
            _assert_equal_to_round_off(a, b)


@needs_compiler
def test_the_music_spectrum_kernel_equals_the_interpreter(monkeypatch: pytest.MonkeyPatch) -> None:
    function = spectrum_function(YANG2014_UCA)
    rng = np.random.default_rng(7)
    m = YANG2014_UCA.n_elements
    inputs = (rng.uniform(0, np.pi, (300, 2)), rng.normal(size=(300, m)), rng.normal(size=(300, m)))
    compiled = evaluate_mapped(function, *inputs)
    monkeypatch.setenv(kernels.KERNELS_ENV, kernels.INTERPRETED)
    for a, b in zip(compiled, evaluate_mapped(function, *inputs), strict=True):
        _assert_equal_to_round_off(a, b)


def _norm_function() -> ca.Function:
    x = ca.SX.sym("x", 3)
    return ca.Function("kernel_test_norm", [x], [ca.sqrt(ca.sumsqr(x)), 2.0 * x])


@pytest.mark.parametrize("n", [1, 7, 9, BLOCK, BLOCK + 1, 3 * BLOCK - 1])
def test_points_beyond_a_block_are_evaluated_block_after_block(n: int) -> None:
    x = np.random.default_rng(n).normal(size=(n, 3))
    norm, twice = evaluate_mapped(_norm_function(), x)
    assert norm.shape == (n, 1, 1) and twice.shape == (n, 3, 1)
    np.testing.assert_allclose(norm[:, 0, 0], np.linalg.norm(x, axis=1), rtol=1e-15)
    assert np.array_equal(twice[:, :, 0], 2.0 * x)


def test_a_shared_input_and_no_points() -> None:
    shared = np.array([3.0, 4.0, 0.0])
    (norm, _) = evaluate_mapped(_norm_function(), shared)
    assert norm.shape == (1, 1, 1) and norm[0, 0, 0] == 5.0
    empty = evaluate_mapped(_norm_function(), np.zeros((0, 3)))
    assert [e.shape for e in empty] == [(0, 1, 1), (0, 3, 1)]


@pytest.fixture
def fresh(tmp_path, monkeypatch: pytest.MonkeyPatch):
    """A new process's kernels: nothing loaded, the cache in ``tmp_path``."""
    monkeypatch.setenv("ATTOPT_CACHE_DIR", str(tmp_path))
    for cached in (kernels._compiled, kernels._mapped, kernels.compiler):
        cached.cache_clear()
    yield tmp_path
    for cached in (kernels._compiled, kernels._mapped, kernels.compiler):
        cached.cache_clear()


@needs_compiler
def test_a_kernel_is_compiled_once_per_machine_and_says_so(
    fresh, capsys: pytest.CaptureFixture
) -> None:
    tmp_path = fresh
    function = _norm_function()
    assert kernel(function).class_name() == "External"
    assert "compiled measurement kernel kernel_test_norm" in capsys.readouterr().err
    (library,) = (tmp_path / "kernels").glob("kernel_test_norm-*.so")
    kernels._compiled.cache_clear()  # as a new process would
    assert kernel(function).class_name() == "External"
    assert capsys.readouterr().err == ""
    assert list((tmp_path / "kernels").iterdir()) == [library]
    x = ca.SX.sym("x", 3)
    changed = ca.Function("kernel_test_norm", [x], [ca.sumsqr(x), x])  # another definition
    kernel(changed)
    assert len(list((tmp_path / "kernels").glob("kernel_test_norm-*.so"))) == 2


@needs_compiler
def test_with_the_cache_off_kernels_are_still_compiled(
    fresh, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ATTOPT_CACHE_DIR", "off")
    compiled = kernel(_norm_function())
    assert compiled.class_name() == "External"
    assert compiled(ca.DM([3.0, 4.0, 0.0]))[0] == 5.0


@pytest.mark.parametrize("cc", ["attopt-no-such-compiler", "false"])
def test_without_a_working_compiler_the_interpreter_is_used(
    cc: str, fresh, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("CC", cc)
    function = _norm_function()
    with caplog.at_level(logging.WARNING, logger=kernels.__name__):
        assert kernel(function) is function
    if cc == "false":  # found but failing: one warning says why
        assert "not compiled" in caplog.text and "failed" in caplog.text
    norm, _ = evaluate_mapped(function, np.array([3.0, 4.0, 0.0]))
    assert norm[0, 0, 0] == 5.0


def test_the_benchmark_times_the_three_paths_on_equal_outputs() -> None:
    from attopt.experiments.benchmarks import kernels as benchmark

    case = benchmark.CASES[0]
    row = benchmark._row(case, case.function(), 5, 1, 0.0)
    assert row["difference"] <= RTOL
    assert all(len(row[path]) == 3 for path in ("matrices", "interpreted", "compiled"))
    assert "| SNR, one observation | 5 |" in benchmark.format_table([row], 1)
    for case in benchmark.CASES:  # the previous path computes what the kernels compute
        function, inputs = case.function(), case.inputs(np.random.default_rng(1), 4)
        previous = benchmark.evaluate_with_matrices(function, *inputs)
        for a, b in zip(evaluate_mapped(function, *inputs), previous, strict=True):
            _assert_equal_to_round_off(a, b)
