"""The ``adsb-sky`` experiment: one setting per sky on common random numbers, and a report
that tabulates every estimator per sky and decides Liu et al. 2023's claims."""

from __future__ import annotations

import functools
import math

import numpy as np
import pandas as pd
import pytest

from attopt.experiments.adsb_sky.experiment import (
    EXPERIMENT,
    SKIES,
    AdsbSkyParameters,
    common_seed,
    grid,
    sky_document,
)
from attopt.experiments.adsb_sky.report import heard_half_the_time_db
from attopt.experiments.adsb_snr import experiment as adsb
from attopt.experiments.environment.adsb_receiver import ReceiverChain
from attopt.experiments.registry import get_experiment
from attopt.experiments.sweep import run_sweep

TINY = {
    "start_utc": "2025-06-02T02:01:00",
    "duration_s": 12.0,
    "step_s": 2.0,
    "traffic": {"n_aircraft": 600},
    "methods": ["nlp"],
    "filters": ["mekf_snr"],
    "gyros": ["mems"],
    "receiver": {"chain": {"table_messages": 200}},
}


def test_each_sky_switches_on_its_own_tables() -> None:
    document = AdsbSkyParameters.model_validate(TINY).model_dump(mode="json")
    tables = {}
    for sky in SKIES:
        parameters = sky_document(document, sky)
        assert "skies" not in parameters
        tables[sky] = (
            parameters["traffic"]["transmitters"],
            parameters["receiver"]["chain"],
            parameters["receiver"]["collisions"],
        )
    assert tables["ideal"] == (None, None, None)
    assert tables["power"][0]["antenna"] == "isotropic" and tables["power"][0]["power"] == "classes"
    assert tables["antennas"][0]["power"] == "nominal" and tables["antennas"][1] is None
    assert tables["chain"][:1] == (None,) and tables["chain"][1]["table_messages"] == 200
    assert tables["collisions"][2]["capture_margin_db"] == 4.0 and tables["collisions"][1] is None
    real = tables["real"]
    assert real[0]["antenna"] == "monopole" and real[1] is not None and real[2] is not None
    assert tables["modelled"] == real
    models = {sky: sky_document(document, sky)["receiver"]["aircraft_model"] for sky in SKIES}
    assert models["modelled"]["antennas"] and models["modelled"]["power"]
    for sky in ("power", "real"):  # the transponder classes, not the antennas
        assert models[sky]["power"] and not models[sky]["antennas"]
    for sky in ("ideal", "antennas", "chain", "collisions"):
        assert models[sky] is None


def test_a_configured_part_keeps_its_numbers_in_every_sky_that_has_it() -> None:
    configured = {**TINY, "traffic": {"n_aircraft": 600, "transmitters": {"class1_share": 0.3}}}
    settings = grid(AdsbSkyParameters.model_validate(configured).model_dump(mode="json"))
    by_sky = {s["sky"]: s["traffic"]["transmitters"] for s in settings}
    assert by_sky["ideal"] is None and by_sky["chain"] is None
    for sky in ("power", "antennas", "real"):
        assert by_sky[sky]["class1_share"] == 0.3


def test_a_configured_aircraft_model_keeps_its_numbers_where_the_receiver_has_one():
    configured = {
        **TINY,
        "receiver": {**TINY["receiver"], "aircraft_model": {"antenna_sigma_db": 1.5}},
    }
    document = AdsbSkyParameters.model_validate(configured).model_dump(mode="json")
    for sky in ("power", "real", "modelled"):
        model = sky_document(document, sky)["receiver"]["aircraft_model"]
        assert model["antenna_sigma_db"] == 1.5
    assert sky_document(document, "chain")["receiver"]["aircraft_model"] is None


def test_every_sky_draws_trial_j_from_one_seed() -> None:
    a = common_seed(np.random.SeedSequence(5, spawn_key=(0, 3)))
    b = common_seed(np.random.SeedSequence(5, spawn_key=(4, 3)))
    assert a.spawn_key == b.spawn_key == (0, 3) and a.entropy == b.entropy == 5


@functools.cache
def _sweep(tmp: str):
    from pathlib import Path

    overrides = {**TINY, "skies": ["ideal", "real"]}
    return run_sweep(
        get_experiment("adsb-sky"),
        trials=1,
        out=Path(tmp) / "out",
        workers=1,
        progress=False,
        overrides=overrides,
    )


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    return _sweep(str(tmp_path_factory.mktemp("adsb-sky")))


def test_the_ideal_sky_is_adsb_snr_on_the_common_seed(sweep) -> None:
    assert len(sweep.failures) == 0
    ideal = sweep.rows[sweep.rows["sky"] == "ideal"].reset_index(drop=True)
    setting = sky_document(AdsbSkyParameters.model_validate(TINY).model_dump(mode="json"), "ideal")
    direct = adsb.trial(setting, np.random.SeedSequence(0, spawn_key=(0, 0)))
    columns = [c for c in direct.columns if c != "runtime_s"]
    pd.testing.assert_frame_equal(
        ideal[columns].reset_index(drop=True), direct[columns].reset_index(drop=True)
    )


def test_the_report_tabulates_every_estimator_per_sky_and_decides_the_claims(sweep) -> None:
    text = (sweep.out_dir / "report.md").read_text()
    assert "## Estimators per sky" in text and "## Integrity" in text
    assert "## Liu et al. 2023's claims under each sky" in text
    for claim in (
        "degree-level single frame",
        "0.15-0.28 deg with the gyro",
        "no gain beyond 100 observations",
        "6 dB usable threshold",
    ):
        lines = [line for line in text.splitlines() if line.startswith(f"| {claim} |")]
        assert len(lines) == 2, claim  # one per sky
    estimators = [line for line in text.splitlines() if line.startswith("| real | ")]
    assert {line.split(" | ")[2] for line in estimators} >= {"nlp", "mekf_snr"}
    assert "| 6 dB usable threshold | ideal | assumed |" in text
    assert "![skies.png](skies.png)" in text and (sweep.out_dir / "skies.png").stat().st_size > 0


def test_the_chain_hears_an_aircraft_half_the_time_between_its_message_points() -> None:
    """Half the epochs needs ``p = ln 2 / 6.2`` per message: below the SNR of 50 % per
    message, above that of ``p = 0``, and above 6 dB for the 2 MHz chain."""
    chain = ReceiverChain(table_messages=200)
    half = heard_half_the_time_db(chain, 2.6e6)
    assert 6.0 < half < 9.5 - 10 * math.log10(2.6 / 2.0)


def test_adsb_sky_is_registered_with_a_quick_variant() -> None:
    assert get_experiment("adsb-sky") is EXPERIMENT
    assert EXPERIMENT.quick_parameters["duration_s"] < AdsbSkyParameters().duration_s


def test_an_accuracy_claim_without_its_estimators_is_not_decided() -> None:
    """A run without gyro-aided rows (``filters = []``) leaves the gyro claim undecided;
    the single-frame claim is still decided from its rows."""
    from attopt.experiments.adsb_sky.report import NO_GYRO, _accuracy_claim

    table = pd.DataFrame(
        {
            "sky": ["ideal"],
            "gyro": [NO_GYRO],
            "method": ["nlp"],
            "valid": [1.0],
            "integrity share": [0.0],
            **{f"RMS {axis} (deg)": [0.5] for axis in ("x", "y", "z")},
        }
    )
    verdict, number = _accuracy_claim(table, True, 0.9, 0.28)("ideal")
    assert verdict == "not decided" and "no gyro-aided estimator" in number
    assert _accuracy_claim(table, False, 0.5, 2.13)("ideal")[0] == "holds"
