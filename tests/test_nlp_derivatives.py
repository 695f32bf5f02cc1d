"""The SNR NLP's compiled gradient and Hessian (:mod:`attopt.solvers.snr.nlp_derivatives`):
the SX derivatives' values to round-off, the same estimates, and used only where they
apply."""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations import kernels
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import snr_function
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.snr import NLP
from attopt.solvers.snr.fit import objective_loss
from attopt.solvers.snr.nlp import TRUNCATED_NLP, _parameter_symbols, parameter_vector
from attopt.solvers.snr.nlp_derivatives import compiled_derivatives
from attopt.solvers.snr.padding import pad_epoch
from tests.contract_cases import CASES
from tests.test_gain_patterns import PATTERNS
from tests.test_kernels import _assert_equal_to_round_off, needs_compiler
from tests.test_nlp_solvers import _noisy_snr
from tests.test_snr_solvers import TRUTH, _epoch, _geometry

TRUNCATED = "truncated_ml"
OBJECTIVES = ("least_squares", TRUNCATED)


def _sx_derivatives(pattern, size: int, objective: str) -> tuple[ca.Function, ca.Function, dict]:
    """CasADi's own gradient and Hessian of the NLP's SX loss (what IPOPT would use)."""
    symbols = _parameter_symbols(size, objective)
    v = ca.SX.sym("v", 3)
    data = [symbols[n] for n in ("los", "boresight", "p0", "noise") if n in symbols]
    predicted = snr_function(pattern, size)(v, symbols["attitude_ref"], *data)
    loss = objective_loss(
        objective,
        symbols["snr"],
        predicted,
        symbols["weights"],
        symbols.get("sigma"),
        symbols.get("threshold"),
    )
    p = ca.vertcat(*(ca.vec(s) for s in symbols.values()))
    gradient = ca.Function("g", [v, p], [loss, ca.gradient(loss, v)])
    hessian = ca.Function("h", [v, p], [ca.triu(ca.hessian(loss, v)[0])])
    return gradient, hessian, symbols


def _epochs():
    """Noisy epochs of each pattern, and the contract case's epoch where CasADi's MX
    Hessian through the map of the rows' losses was NaN (a first version)."""
    for name, pattern in PATTERNS.items():
        rng = np.random.default_rng(11)
        geometry = _geometry(rng, TRUTH, (10, 10), pattern=pattern)
        yield name, _epoch(geometry, geometry[3] + rng.normal(size=20), pattern=pattern), TRUTH
    drawn = CASES["nlp_truncated"].draw(1000, True)
    yield "contract case", drawn.problem.measurements[0].epoch, drawn.truth


@needs_compiler
@pytest.mark.parametrize("objective", OBJECTIVES)
def test_compiled_derivatives_equal_casadis_own_to_round_off(objective):
    rng = np.random.default_rng(3)
    for name, problem, truth in _epochs():
        start = Rotation.from_rotvec(np.radians([4.0, -3.0, 2.0])) * truth
        padded = pad_epoch(problem, start.as_matrix())
        threshold = problem.threshold_db if objective == TRUNCATED else None
        p = parameter_vector(padded, start.as_matrix(), threshold)
        gradient, hessian, symbols = _sx_derivatives(problem.pattern, padded.size, objective)
        compiled = compiled_derivatives(
            problem.pattern, padded.size, objective, NlpOptions(), symbols
        )
        assert {f.class_name() for f in compiled.values()} == {"External"}, name
        for v in [np.zeros(3), *rng.normal(scale=0.05, size=(3, 3))]:
            f, g = (np.asarray(x.full()) for x in compiled["grad_f"](v, p))
            expected_f, expected_g = (np.asarray(x.full()) for x in gradient(v, p))
            _assert_equal_to_round_off(f, expected_f)
            _assert_equal_to_round_off(g, expected_g)
            h = np.asarray(ca.densify(compiled["hess_lag"](v, p, 2.0, np.zeros(0))).full())
            expected_h = 2.0 * np.asarray(ca.densify(hessian(v, p)).full())
            assert np.isfinite(expected_h).all(), name
            _assert_equal_to_round_off(h, expected_h)


@needs_compiler
@pytest.mark.parametrize("estimator", [NLP, TRUNCATED_NLP], ids=lambda e: e.name)
def test_the_estimates_are_those_of_casadis_derivatives(estimator, monkeypatch):
    """From a start 5 deg off and without a prior (the multi-start), epoch by epoch: the
    same attitudes to the stopping tolerance, whichever derivatives IPOPT used (``tol /
    lambda_min(F)``, ~1e-9 rad here; measured up to 6e-10 rad where the round-off of
    the derivatives changed IPOPT's last step, 3e-16 over 60 s of ``adsb-snr``)."""
    snapshots = [Snapshot.of(SnrMeasurement(_noisy_snr(seed))) for seed in range(4)]
    start = Rotation.from_rotvec(np.radians([3.0, -3.0, 2.5])) * TRUTH
    compiled = [estimator.solve(s, start) for s in snapshots]
    unstarted = estimator.solve_sequence(snapshots[:2])
    monkeypatch.setenv(kernels.KERNELS_ENV, kernels.INTERPRETED)
    interpreted = [estimator.solve(s, start) for s in snapshots]
    for a, b in zip(compiled, interpreted, strict=True):
        assert float((a.attitude * b.attitude.inv()).magnitude()) < 1e-8
        np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-6)
    again = estimator.solve_sequence(snapshots[:2])
    np.testing.assert_allclose(again.quaternion, unstarted.quaternion, atol=1e-8)


@pytest.mark.parametrize(
    ("objective", "options", "mode"),
    [
        (TRUNCATED, NlpOptions(solver="sqpmethod"), None),
        (TRUNCATED, NlpOptions(hessian_approximation="limited-memory"), None),
        (TRUNCATED, NlpOptions(), kernels.INTERPRETED),
    ],
    ids=["SQP method", "limited memory", "interpreted kernels"],
)
def test_casadis_own_derivatives_where_the_compiled_ones_do_not_apply(
    objective, options, mode, monkeypatch
):
    if mode is not None:
        monkeypatch.setenv(kernels.KERNELS_ENV, mode)
    symbols = _parameter_symbols(16, objective)
    assert compiled_derivatives(LIU2023_HELIX, 16, objective, options, symbols) == {}


def test_an_sqp_truncated_nlp_still_solves():
    """The SQP method keeps CasADi's derivatives of the same loss."""
    snapshot = Snapshot.of(SnrMeasurement(_noisy_snr(12)))
    start = Rotation.from_rotvec(np.radians([3.0, -3.0, 2.5])) * TRUTH
    ipopt = TRUNCATED_NLP.solve(snapshot, start)
    sqp = replace(TRUNCATED_NLP, options=NlpOptions(solver="sqpmethod")).solve(snapshot, start)
    assert float((ipopt.attitude * sqp.attitude.inv()).magnitude()) < 1e-7
