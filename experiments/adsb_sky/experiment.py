"""Experiment ``adsb-sky``: which of Liu et al. 2023's conclusions survive the real sky.

The ``adsb-snr`` scenario and estimators (:mod:`attopt.experiments.adsb_snr.experiment`),
run once per *sky* (``skies``), each a setting of the sweep:

* ``ideal``: Liu et al. 2023 sec. 5.1 (known equal powers, isotropic aircraft
  antennas, Gaussian 1 dB SNRs above a hard 6 dB threshold, no collisions);
* ``power``: real transponder powers alone (``[traffic.transmitters]`` with
  ``antenna = "isotropic"``);
* ``antennas``: real aircraft antennas alone, with bank and diversity
  (``power = "nominal"``);
* ``chain``: the simulated 1090ES receiver chain alone (``[receiver.chain]``);
* ``collisions``: message collisions alone (``[receiver.collisions]``);
* ``real``: all of them together;
* ``modelled``: the real sky, with the receiver's whole aircraft model
  (``[receiver.aircraft_model]``): every estimator is told each message's expected
  EIRP, the transponder classes' mean power through the better placed antenna in
  level flight, the single-frame methods the model's uncertainty, and the filters
  with offsets the random walk of what that antenna model leaves out.

The quick variant (300 s) also runs the estimators with one power offset per
aircraft: the batch smoother ``fg_batch_offsets`` (started from the single-frame NLP,
docs/smoother.md) and ``mekf_offsets_snr`` and ``usque_offsets_snr``, the MEKF and
USQUE with each aircraft's offset as a state (docs/filters.md).  The full hour does not
by default; ask for them with ``filters``.  The filters' cost grows with the cube of
the aircraft heard at once (3.9 s for the first 300 s of the pass, 652 s for the first
1,200 s), so over the hour they would take hours; the smoother's is linear in the pass
(``python -m attopt.experiments.benchmarks.offsets``, docs/benchmarks.md).

Each part takes its numbers from this experiment's own tables where a config gives them
(``[traffic.transmitters]``, ``[receiver.chain]``, ``[receiver.collisions]``), else
their documented defaults (:mod:`attopt.experiments.adsb_snr.sky`); the ``ideal`` sky
leaves them all out.  Where the powers are real, the receiver knows the transponder
classes (``[receiver.aircraft_model]`` with ``antennas = false`` in ``power`` and
``real``): each message's ``10 lg P0`` carries the classes' mean power and the
single-frame methods are told their spread, as a user who knows the classes would
configure them; only in ``modelled`` does the receiver also model the aircraft
antennas.  Nothing else about the sky is told to any estimator.

The skies are compared on common random numbers: trial ``j`` of every sky draws from
the same seed, ``SeedSequence(root, spawn_key=(0, j))``, so the
paper's SNR noise, the gyros, the transmitters and the messages are the same draws in
every sky that has them, and a difference between two skies is the sky's.

Rows are those of ``adsb-snr`` with the setting's ``sky`` column; the report
(:mod:`attopt.experiments.adsb_sky.report`) tabulates, per sky and estimator, the
observations per epoch, the RMS error and its ratio to the bound, the integrity share and
the valid fraction, and answers the paper's claims with the numbers that decide them.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
import pandas as pd
from pydantic import Field

from attopt.experiments.adsb_sky.report import report
from attopt.experiments.adsb_snr import experiment as adsb
from attopt.experiments.adsb_snr.filters import DEFAULT_FILTERS
from attopt.experiments.experiment import Experiment, Setting

QUICK_FILTERS = [*DEFAULT_FILTERS, "fg_batch_offsets", "mekf_offsets_snr", "usque_offsets_snr"]
"""The quick variant's filters: ``adsb-snr``'s and the three with offsets (module docstring)."""

Sky = Literal["ideal", "power", "antennas", "chain", "collisions", "real", "modelled"]
SKIES: tuple[str, ...] = (
    "ideal",
    "power",
    "antennas",
    "chain",
    "collisions",
    "real",
    "modelled",
)
"""Every sky, in the report's order."""


class AdsbSkyParameters(adsb.AdsbSnrParameters):
    """Parameters of ``adsb-sky``: ``adsb-snr``'s, and the skies to run (module
    docstring)."""

    skies: list[Sky] = Field(
        default_factory=lambda: list(SKIES),
        min_length=1,
        description=(
            "Skies to compare: ideal, power, antennas, chain, collisions, real, modelled."
        ),
    )


def sky_document(parameters: Mapping[str, Any], sky: str) -> dict[str, Any]:
    """The ``adsb-snr`` parameters of ``sky`` (module docstring): ``parameters`` without
    ``skies``, with the sky's tables, from ``parameters``' own where it has them.

    Example::

        >>> document = AdsbSkyParameters().model_dump(mode="json")
        >>> power = sky_document(document, "power")
        >>> power["traffic"]["transmitters"]["antenna"], power["receiver"]["chain"]
        ('isotropic', None)
    """
    document = copy.deepcopy(dict(parameters))
    document.pop("skies", None)
    traffic, receiver = document["traffic"], document["receiver"]
    transmitters = traffic.get("transmitters") or {}
    chain, collisions = receiver.get("chain") or {}, receiver.get("collisions") or {}
    whole = ("real", "modelled")
    real = {**transmitters, "power": "classes", "antenna": "monopole"}
    traffic["transmitters"] = {
        "power": {**transmitters, "power": "classes", "antenna": "isotropic"},
        "antennas": {**transmitters, "power": "nominal", "antenna": "monopole"},
        **dict.fromkeys(whole, real),
    }.get(sky)
    receiver["chain"] = chain if sky in ("chain", *whole) else None
    receiver["collisions"] = collisions if sky in ("collisions", *whole) else None
    model = receiver.get("aircraft_model") or {}
    receiver["aircraft_model"] = {
        "power": {**model, "antennas": False},
        "real": {**model, "antennas": False},
        "modelled": model,
    }.get(sky)
    return adsb.AdsbSnrParameters.model_validate(document).model_dump(mode="json")


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per sky of ``skies``: its ``adsb-snr`` parameters and ``sky``."""
    validated = AdsbSkyParameters.model_validate(dict(parameters)).model_dump(mode="json")
    return [{"sky": sky, **sky_document(validated, sky)} for sky in validated["skies"]]


def common_seed(seed: np.random.SeedSequence) -> np.random.SeedSequence:
    """The seed of trial ``j`` shared by every sky: ``spawn_key`` ``(0, j)`` in place of the
    runner's ``(i, j)`` for setting ``i`` (module docstring)."""
    return np.random.SeedSequence(seed.entropy, spawn_key=(0, *seed.spawn_key[1:]))


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """``adsb-snr``'s trial of the setting's sky, from the trial's common seed."""
    parameters = {key: value for key, value in setting.items() if key != "sky"}
    return adsb.trial(parameters, common_seed(seed))


EXPERIMENT = Experiment(
    name="adsb-sky",
    summary=(
        "Liu et al. 2023 under the real sky: every ADS-B estimator with real transponder "
        "powers, aircraft antennas, a simulated receiver chain and message collisions"
    ),
    schema=AdsbSkyParameters,
    grid=grid,
    trial=trial,
    default_trials=1,
    quick_trials=1,
    quick_parameters={"duration_s": 300.0, "filters": QUICK_FILTERS},
    group_by=("method", "gyro"),
    report=report,
    summary_columns=adsb.summary_columns,
    compiled_loops=("wahba.quest", "filters", "smoother"),
)
