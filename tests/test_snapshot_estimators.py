"""The snapshot estimators' packages follow the contract (``solvers/estimator.py``): each
defines ``ESTIMATORS``, instances of frozen dataclasses with the registry's names, which
pickle and are configured by ``dataclasses.replace``."""

from __future__ import annotations

import dataclasses
import importlib
import pickle

import pytest

from attopt.solvers.estimator import SnapshotEstimator

PACKAGES = {
    "attopt.solvers.wahba": ["triad", "svd", "q_method", "quest", "foam", "sdp"],
    "attopt.solvers.snr": ["deterministic", "nlse", "nlp", "nlp_truncated"],
    "attopt.solvers.geo": ["geo_cone", "geo_lsq"],
    "attopt.solvers.map_nlp": ["map_nlp"],
}


@pytest.mark.parametrize("package", PACKAGES)
def test_estimators_of_each_package(package):
    estimators = importlib.import_module(package).ESTIMATORS
    assert isinstance(estimators, tuple)
    assert [e.name for e in estimators] == PACKAGES[package]
    for estimator in estimators:
        assert isinstance(estimator, SnapshotEstimator)
        assert dataclasses.is_dataclass(estimator) and estimator.accepts
        with pytest.raises(dataclasses.FrozenInstanceError):
            estimator.name = "other"  # type: ignore[misc]
        assert pickle.loads(pickle.dumps(estimator)) == estimator
        renamed = dataclasses.replace(estimator, name="renamed")
        assert renamed.name == "renamed" and type(renamed) is type(estimator)
        assert repr(estimator).startswith(f"<snapshot estimator {estimator.name!r}")
