"""One NLP, two solvers: IPOPT and CasADi's SQP method (``NlpOptions.solver``).

The SNR NLP and the MAP NLP are built once per size and solved by either plugin
(:mod:`attopt.solvers.nlpsol`).  Both recover noise-free measurements of every type
(tests/test_map_nlp.py); here they reach the same minimum of noisy epochs, and an SQP
solve that stops without converging after at least one iteration is repeated by IPOPT
(:func:`attopt.solvers.snr.initialisation.increment_solve`).
"""

from __future__ import annotations

import pickle
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import attopt
from attopt.formulations.errors import ConvergenceError
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.map_nlp import MAP_NLP
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.snr import NLP
from attopt.solvers.snr.initialisation import increment_solve
from attopt.solvers.snr.nlp import TRUNCATED_NLP, nlp_solver, parameter_vector
from attopt.solvers.snr.padding import pad_epoch
from tests.test_map_nlp import angle
from tests.test_snr_solvers import TRUTH, _epoch, _geometry

SQP = NlpOptions(solver="sqpmethod")


def _noisy_snr(seed: int, per_antenna: tuple[int, int] = (10, 10)):
    rng = np.random.default_rng(seed)
    geometry = _geometry(rng, TRUTH, per_antenna)
    return _epoch(geometry, geometry[3] + rng.normal(size=sum(per_antenna)))


def test_options_are_validated_and_name_their_solver():
    assert NlpOptions().label == "IPOPT" and SQP.label == "SQP"
    assert attopt.NlpOptions is NlpOptions
    for bad in ({"solver": "snopt"}, {"hessian_approximation": "bfgs"}, {"tol": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            NlpOptions(**bad)
    options = SQP.nlpsol_options()
    assert options["tol_du"] == SQP.tol and options["max_iter"] == SQP.max_iter
    assert not any(key.startswith("ipopt.") for key in options)


@pytest.mark.parametrize("estimator", [NLP, TRUNCATED_NLP, MAP_NLP], ids=lambda e: e.name)
def test_both_solvers_reach_the_same_minimum_of_noisy_epochs(estimator):
    """From a start 5 deg off, within the stopping tolerance: ``tol / lambda_min(F)``,
    ~1e-9 rad here (:mod:`attopt.solvers.snr.nlp`); the covariances and losses, evaluated
    at the estimate, agree to the same order."""
    sqp = replace(estimator, options=SQP)
    start = Rotation.from_rotvec(np.radians([3.0, -3.0, 2.5])) * TRUTH
    for seed in range(6):
        snapshot = Snapshot.of(SnrMeasurement(_noisy_snr(seed)))
        ipopt, other = estimator.solve(snapshot, start), sqp.solve(snapshot, start)
        assert angle(ipopt.attitude, other.attitude) < 1e-7, seed
        np.testing.assert_allclose(other.covariance, ipopt.covariance, rtol=1e-5)
        assert other.loss == pytest.approx(ipopt.loss, rel=1e-9)


def _local(problem, options, solver=None, start=TRUTH):
    a_ref = start.as_matrix()
    padded = pad_epoch(problem, a_ref)
    build = solver or (lambda o: nlp_solver(LIU2023_HELIX, padded.size, o))
    return increment_solve(build, options, parameter_vector(padded, a_ref), start)


def test_an_sqp_solve_that_stops_is_repeated_by_ipopt():
    """The SQP method limited to one iteration stops short; IPOPT, repeating the solve
    from the same start, returns exactly its own solution."""
    problem = _noisy_snr(3)
    start = Rotation.from_rotvec(np.radians([10.0, -8.0, 6.0])) * TRUTH
    size = pad_epoch(problem, start.as_matrix()).size
    calls = []

    def build(options: NlpOptions):
        calls.append(options.solver)
        limited = replace(options, max_iter=1) if options.solver == "sqpmethod" else options
        return nlp_solver(LIU2023_HELIX, size, limited)

    rescued = _local(problem, SQP, build, start)
    ipopt = _local(problem, NlpOptions(), start=start)
    assert calls == ["sqpmethod", "ipopt"]
    assert rescued.converged
    assert replace(rescued, attitude=None) == replace(ipopt, attitude=None)
    np.testing.assert_array_equal(rescued.attitude.as_quat(), ipopt.attitude.as_quat())


def test_a_failure_of_both_names_both_and_fails_the_epoch():
    problem = _noisy_snr(4)
    start = Rotation.from_rotvec(np.radians([10.0, -8.0, 6.0])) * TRUTH
    options = replace(SQP, max_iter=1)
    result = _local(problem, options, start=start)
    assert not result.converged
    assert result.status == (
        "Maximum_Iterations_Exceeded (IPOPT, after SQP's Maximum_Iterations_Exceeded)"
    )
    with pytest.raises(ConvergenceError, match=r"^nlp: SQP: Maximum_Iterations_Exceeded \(IPOPT"):
        replace(NLP, options=options).solve(Snapshot.of(SnrMeasurement(problem)), prior=start)


def test_a_start_where_the_loss_is_undefined_is_not_repeated():
    """A start that points every antenna away from its aircraft (the loss is undefined
    there: ``lg cos(alpha)`` of a negative cosine) stops both solvers at the start; IPOPT
    is not asked again."""
    problem = _noisy_snr(5)
    start = Rotation.from_rotvec([np.pi, 0.0, 0.0]) * TRUTH
    size = pad_epoch(problem, start.as_matrix()).size
    calls = []

    def build(options: NlpOptions):
        calls.append(options.solver)
        return nlp_solver(LIU2023_HELIX, size, options)

    result = _local(problem, SQP, build, start)
    assert calls == ["sqpmethod"] and not result.converged and result.iterations == 0
    assert not _local(problem, NlpOptions(), start=start).converged


@pytest.mark.parametrize("estimator", [NLP, MAP_NLP], ids=lambda e: e.name)
def test_the_sqp_method_is_deterministic_and_picklable(estimator):
    """Sweeps ship estimators to worker processes: a pickled SQP estimator solves to the
    same bits, twice, without a prior (multi-start) and from a start."""
    sqp = replace(estimator, options=SQP)
    copy = pickle.loads(pickle.dumps(sqp))
    assert copy == sqp
    snapshots = [Snapshot.of(SnrMeasurement(_noisy_snr(seed))) for seed in (7, 8)]
    tracks = [s.solve_sequence(snapshots) for s in (sqp, copy, sqp)]
    for track in tracks[1:]:
        np.testing.assert_array_equal(track.quaternion, tracks[0].quaternion)
        np.testing.assert_array_equal(track.covariance, tracks[0].covariance)
    assert tracks[0].valid.all()
