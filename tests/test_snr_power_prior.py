"""The SNR solvers' power prior: transmitters whose powers are known only in distribution
(``power_offset_mean_db``, ``power_offset_sigma_db``; solvers/snr/driver.py)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from attopt.experiments.adsb_snr.experiment import AdsbSnrParameters, snr_snapshots, trial_pass
from attopt.experiments.reporting.statistics import integrity
from attopt.solvers.registry import estimator

SEED = np.random.SeedSequence(0, spawn_key=(0, 0))
OFFSET_SIGMA_DB = 2.0


@functools.cache
def _pass():
    """Two minutes of the paper's pass with every aircraft's power off by N(0, 2 dB)."""
    parameters = AdsbSnrParameters.model_validate(
        {"duration_s": 120.0, "traffic": {"power_offset_sigma_db": OFFSET_SIGMA_DB}}
    )
    scenario, noisy = trial_pass(parameters, SEED)
    return scenario, snr_snapshots(noisy.epochs), noisy.epochs


def _rows(name: str, **options):
    scenario, snapshots, _ = _pass()
    frame = estimator(name, **options).solve_sequence(snapshots).to_dataframe(scenario.truth)
    return frame.assign(method=name)


@pytest.mark.parametrize("name", ["nlp", "nlp_truncated", "deterministic"])
def test_told_the_spread_the_solvers_are_valid_and_consistent(name: str) -> None:
    """Valid and consistent; the one-step methods flag the epochs started without a prior
    whose data a second minimum fits about as well (``ambiguous``; measured: 9 and 7 of
    the 120 epochs for the NLP and the truncated NLP, at the start of the pass)."""
    rows = _rows(name, power_offset_sigma_db=OFFSET_SIGMA_DB)
    statistic = integrity(rows, ["method"]).iloc[0]
    assert statistic["valid_fraction"] > 0.9
    flagged = rows.loc[~rows["valid"], "reason"]
    assert flagged.str.startswith(("ambiguous", "model mismatch", "fewer than two")).all()
    assert statistic["share_beyond"] <= 1e-3
    assert 1.0 < statistic["mean_nees"] < 3.5


def test_not_told_the_residual_test_flags_the_epochs() -> None:
    rows = _rows("nlp")
    assert rows["valid"].mean() < 0.05
    assert rows.loc[~rows["valid"], "reason"].str.startswith("model mismatch").all()


def test_the_prior_raises_p0_by_its_mean_and_widens_each_sigma() -> None:
    _, _, epochs = _pass()
    epoch = epochs[3]
    solver = estimator("nlp", power_offset_mean_db=-0.5, power_offset_sigma_db=1.5)
    told = solver.with_power_prior(epoch)
    np.testing.assert_array_equal(told.p0_dbw, epoch.p0_dbw - 0.5)
    np.testing.assert_allclose(told.sigma_db, np.hypot(epoch.sigma_db, 1.5), rtol=1e-15)
    assert estimator("nlp").with_power_prior(epoch) is epoch


def test_a_negative_spread_is_refused() -> None:
    with pytest.raises(ValueError, match="non-negative"):
        estimator("nlse", power_offset_sigma_db=-1.0)
