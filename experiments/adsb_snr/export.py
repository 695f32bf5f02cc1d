"""A simulated ``adsb-snr`` pass as a recorded pass (:mod:`attopt.experiments.recorded`).

:func:`export` lays out what :func:`~attopt.experiments.adsb_snr.experiment.trial`
simulates for ``(setting, seed)``, with the experiment's own functions
(:func:`~attopt.experiments.adsb_snr.experiment.trial_pass`,
:func:`~attopt.experiments.adsb_snr.filters.gyro_inputs`):

* ``snr``: every received message (Liu et al. 2023 sec. 5.1: measured SNR at or
  above the threshold), in the trial's order, with its antenna, its aircraft
  (``transmitter``) and the aircraft's ECI position, the orbit-frame line of
  sight, the isotropic power ``10 lg P0`` and the SNR sigma (as the receiver decodes
  them: from the broadcast position, wrong for a ``[traffic.spoofer]`` aircraft);
* ``epochs``: every epoch of the pass, also those without a received message;
* ``[snr]``: the receiver's noise power and threshold, each antenna's body
  boresight and gain pattern, and ``truncated`` for the filters' SNR model
  (``filter_snr_model``; the snapshot methods use the untruncated model of
  eq. 19 or their own);
* ``gyro`` and ``[gyro]``: the first gyro of ``gyros`` (its samples from child
  stream 1 of the trial's seed, as in the trial), with ``[prior]``, the filters'
  prior in ECI;
* ``position``: the satellite's ECI position and velocity at the epochs (the
  orbit frames of the filters), and ``truth``: the true orbit -> body attitude.

An estimate of the exported pass reproduces, bit for bit, the trial's rows of
the snapshot methods (``methods``) and of the filters and smoothers on the
SNRs for the first gyro, each with the registry's default options (the
experiment's ``deterministic_min_per_antenna`` and ``offset_prior_sigma_db`` are
options, not data).  ``mekf_paper`` filters the NLSE's Euler angles, which
are not measurements of the pass; ``fg_batch`` starts from ``fg_online`` in the
trial.  To export another gyro, list it first in ``gyros``.
"""

from __future__ import annotations

import math

import numpy as np

from attopt.experiments.adsb_snr.experiment import AdsbSnrParameters, trial_pass
from attopt.experiments.adsb_snr.filters import gyro_inputs
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry
from attopt.experiments.environment.orbit import ecef_to_eci_matrices, window_times
from attopt.experiments.experiment import Setting
from attopt.experiments.recorded.metadata import (
    INERTIAL,
    ORBIT,
    AntennaEntry,
    PassMetadata,
    SnrEntry,
    gyro_entry,
    pattern_entry,
)
from attopt.experiments.recorded.recorded_pass import RecordedPass
from attopt.experiments.recorded.records import (
    epochs_table,
    gyro_table,
    position_table,
    prior_entry,
    snr_table,
    truth_table,
)


def export(setting: Setting, seed: np.random.SeedSequence) -> RecordedPass:
    """Trial ``seed`` of ``setting`` as a :class:`RecordedPass` (module docstring).

    Example::

        >>> import numpy as np
        >>> from attopt.experiments.adsb_snr.experiment import EXPERIMENT
        >>> from attopt.experiments.adsb_snr.export import export
        >>> setting = {**EXPERIMENT.parameters, "duration_s": 30.0}
        >>> export(setting, np.random.SeedSequence(0))
        RecordedPass(attitude orbit, Pass(30 epochs, t 0-29 s, 30 with measurements),
                     tables epochs, gyro, snr, position, truth)
    """
    parameters = AdsbSnrParameters.model_validate(setting)
    scenario, noisy = trial_pass(parameters, seed)
    geometry = build_adsb_geometry(parameters)
    inputs = gyro_inputs(parameters, seed, 0)
    received = np.flatnonzero(noisy.received)
    epoch = scenario.epoch_index[received]
    decoded = noisy.decoded
    _, times = window_times(parameters.start_utc, parameters.duration_s, parameters.step_s)
    to_eci = ecef_to_eci_matrices(times)[epoch]
    antennas = tuple(
        AntennaEntry(
            name=f"antenna{i + 1}",
            boresight_body=tuple(geometry.boresights_body[i].tolist()),
            pattern=pattern_entry(antenna.gain.pattern()),
        )
        for i, antenna in enumerate(parameters.antennas)
    )
    metadata = PassMetadata(
        description="adsb-snr: a simulated pass of ADS-B SNRs (Liu et al. 2023)",
        start_utc=geometry.start_utc,
        attitude_frame=ORBIT,
        position_frame=INERTIAL,
        gyro=gyro_entry(inputs.model),
        snr=SnrEntry(
            noise_dbw=scenario.link_budget.noise_power_dbw,
            threshold_db=noisy.threshold_db,
            truncated=parameters.filter_snr_model == "truncated"
            and math.isfinite(noisy.threshold_db),
            antennas=antennas,
        ),
        prior=prior_entry(inputs.prior, INERTIAL),
    )
    tables = {
        "epochs": epochs_table(scenario.t),
        "gyro": gyro_table(inputs.record),
        "snr": snr_table(
            t=scenario.t[epoch],
            antenna=scenario.antenna[received],
            transmitter=scenario.aircraft[received],
            transmitter_km=np.einsum("nij,nj->ni", to_eci, decoded.aircraft_ecef_km[received]),
            los=decoded.los_orbit[received],
            p0_dbw=decoded.p0_dbw[received],
            snr_db=noisy.measured_db[received],
            sigma_db=np.broadcast_to(noisy.sigma_db, noisy.received.shape)[received],
        ),
        "position": position_table(geometry.t, geometry.position_eci_km, geometry.velocity_eci_kms),
        "truth": truth_table(scenario.t, scenario.truth),
    }
    return RecordedPass(metadata, tables)
