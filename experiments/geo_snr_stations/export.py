"""A simulated ``geo-snr-stations`` pass as a recorded pass (:mod:`attopt.experiments.recorded`).

:func:`export` lays out what :func:`~attopt.experiments.geo_snr_stations.experiment.trial`
simulates for ``(setting, seed)`` and gives its gyro-aided filters (USQUE of
Pimienta-Penalver and Crassidis sec. V.B and the other pass estimators), with the
experiment's own functions:

* ``snr``: the measured SNRs of the filter stations (``filter_stations``; only those,
  as the filters get them: :func:`~attopt.experiments.geo_snr_stations.experiment.filter_snrs`,
  :func:`~attopt.experiments.geo_snr_stations.experiment.filter_measurements`).  The
  receiving antenna is the broadcaster's dish on the satellite (antenna 0, boresight
  body ``+z``), the "transmitters" are the ground stations: ``transmitter`` is the
  station's index in ``[[stations]]``, ``transmitter_{x,y,z}_km`` its ECI position at
  the epoch, ``los_*`` the unit line of sight satellite -> station in ECI and
  ``p0_dbw`` its isotropic received power (the link budget of eq. 7), exactly as the
  trial's measurements hold them; ``[snr]`` has the dish pattern (eq. 5), the noise
  power and no reception threshold (``-inf``: stations that do not hear the satellite
  are left out), as :func:`~attopt.formulations.geo_link.geo_snr_epoch` sets them;
* ``gyro``: the assumed body rate of the nominal slew, one sample per epoch, with its
  model (:func:`~attopt.experiments.geo_snr_stations.experiment.filter_gyro`);
* ``[prior]``: the filters' prior
  (:func:`~attopt.experiments.geo_snr_stations.experiment.filter_prior`, its boresight
  the cone intersection's at the first epoch);
* ``epochs``: every epoch of the pass (one may have no filter-station SNR);
* ``position``: the satellite's ECI position (no velocity: the scenario keeps none and
  no frame needs it);
* ``truth``: the true ECI -> body attitude.

The attitude is relative to ECI (``attitude_frame = "eci"``): the lines of sight are
ECI (:meth:`~attopt.experiments.geo_snr_stations.scenario.GeoSnrScenario.measurement`),
the truth is ECI -> body and the assumed rate is relative to ECI, so no orbit frame is
involved and ``gyro_pass`` is the pass the trial's filters solve.

Which rows of the trial an estimate of the exported pass reproduces.  The registry
filters (``usque``, ``mekf``, ...) on ``gyro_pass``, saved and loaded or not, give the
trial's filter tracks bit for bit when run with the trial's options
(:func:`~attopt.experiments.geo_snr_stations.experiment.configured`: no innovation gate,
a 90 deg validity limit).  ``attopt estimate`` runs the registry's defaults (an
innovation gate, a 15 deg validity limit), so its ``usque`` and ``mekf`` rows are the
trial's only where neither acts, typically without the manoeuvre (``sigma``,
``valid`` and the quaternions bit for bit; ``err_z_deg`` is the trial's
``yaw_err_deg``, while the trial's ``err_{x,y}_deg`` are pointing errors,
:func:`attopt.experiments.metrics.pointing_error`, not ``attopt estimate``'s attitude
errors, and the trial's ``nees`` is over the two axes across the boresight, not
``attopt estimate``'s three).  Not reproduced: ``usque_detect`` (manoeuvre detection and restarts,
:mod:`attopt.solvers.geo.manoeuvre`, not a registry estimator), the smoothers the trial
starts from it (``fg_batch``, ``fg_batch_offsets``), ``cone`` (``geo_cone`` on these
stations, but its rows are a boresight's: pointing error, two-axis NEES, Cramer-Rao
bound), ``lsq`` and the one-step solvers (on every station that hears the satellite,
not only the filter stations).  The trial's measurements carry no transmitter
identifiers, the exported ones do, so an estimator with one power offset per
transmitter (``fg_batch_offsets``) runs on the export but not in the trial; every other
estimator ignores them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from attopt.experiments.experiment import Setting
from attopt.experiments.geo_snr_stations.experiment import (
    cone_pointing,
    cone_start,
    filter_gyro,
    filter_measurements,
    filter_prior,
    filter_snrs,
    filter_station_indices,
    simulate,
)
from attopt.experiments.geo_snr_stations.scenario import GeoSnrScenario
from attopt.experiments.recorded.metadata import (
    INERTIAL,
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
from attopt.formulations.snr_measurement import SnrMeasurement

ANTENNA = "dish"
"""The name of the one receiving antenna: the broadcaster's dish."""


def snr_rows(
    scenario: GeoSnrScenario, filter_snr: np.ndarray, measurements: list[SnrMeasurement | None]
) -> pd.DataFrame:
    """The ``snr`` table of ``measurements`` (one per epoch or ``None``, from the SNRs
    ``filter_snr`` ``(N, m)``): per epoch its stations in index order, each with the
    values its :class:`~attopt.formulations.snr_problem.SnrEpoch` holds (module
    docstring)."""
    heard = [k for k, measurement in enumerate(measurements) if measurement is not None]
    epochs = [measurements[k].epoch for k in heard]
    stations = [np.flatnonzero(np.isfinite(filter_snr[k])) for k in heard]
    return snr_table(
        t=np.concatenate([np.full(e.m, scenario.t[k]) for k, e in zip(heard, epochs, strict=True)]),
        antenna=np.concatenate([e.antenna for e in epochs]),
        transmitter=np.concatenate(stations),
        transmitter_km=np.concatenate(
            [scenario.stations_eci_km[k, s] for k, s in zip(heard, stations, strict=True)]
        ),
        los=np.concatenate([e.los_orbit for e in epochs]),
        p0_dbw=np.concatenate([e.p0_dbw for e in epochs]),
        snr_db=np.concatenate([e.snr_db for e in epochs]),
        sigma_db=np.concatenate([np.broadcast_to(e.sigma_db, (e.m,)) for e in epochs]),
    )


def snr_entry(measurements: list[SnrMeasurement | None]) -> SnrEntry:
    """``[snr]``: the dish (boresight, pattern), noise power and threshold of the
    measurements (the same at every epoch: the first one's)."""
    epoch = next(m for m in measurements if m is not None).epoch
    (boresight,) = np.asarray(epoch.boresights_body, dtype=float)
    return SnrEntry(
        noise_dbw=epoch.noise_dbw,
        threshold_db=epoch.threshold_db,
        antennas=(
            AntennaEntry(
                name=ANTENNA,
                boresight_body=tuple(boresight.tolist()),
                pattern=pattern_entry(epoch.pattern),
            ),
        ),
    )


def export(setting: Setting, seed: np.random.SeedSequence) -> RecordedPass:
    """Trial ``seed`` of ``setting`` as a :class:`RecordedPass`: the pass its gyro-aided
    filters solve, with the truth (module docstring).

    Raises:
        ValueError: no cone intersection at the first epoch (the trial raises it too).

    Example::

        >>> import numpy as np
        >>> from attopt.experiments.geo_snr_stations.experiment import EXPERIMENT
        >>> from attopt.experiments.geo_snr_stations.export import export
        >>> setting = {**EXPERIMENT.parameters, "duration_s": 600.0, "manoeuvre": False}
        >>> recorded = export(setting, np.random.SeedSequence(0))
        >>> recorded.metadata.attitude_frame, sorted(recorded.tables)
        ('eci', ['epochs', 'gyro', 'position', 'snr', 'truth'])
        >>> sorted(set(recorded.tables["snr"]["transmitter"]))  # Surabaya, General Santos, Labuan
        [2, 6, 7]
    """
    parameters, scenario, snr = simulate(setting, seed)
    stations = filter_station_indices(parameters, scenario)
    start = cone_start(cone_pointing(parameters, scenario, snr))
    filter_snr = filter_snrs(snr, stations)
    measurements = filter_measurements(scenario, filter_snr)
    gyro = filter_gyro(parameters, scenario)
    metadata = PassMetadata(
        description=(
            "geo-snr-stations: a GEO broadcaster's SNRs at its filter stations "
            "(Pimienta-Penalver and Crassidis)"
        ),
        start_utc=parameters.start_utc,
        attitude_frame=INERTIAL,
        position_frame=INERTIAL,
        gyro=gyro_entry(gyro.model),
        snr=snr_entry(measurements),
        prior=prior_entry(filter_prior(parameters, seed, scenario, start), INERTIAL),
    )
    t = scenario.t
    tables = {
        "epochs": epochs_table(t),
        "gyro": gyro_table(gyro),
        "snr": snr_rows(scenario, filter_snr, measurements),
        "position": position_table(
            t, scenario.satellite_eci_km, np.full_like(scenario.satellite_eci_km, np.nan)
        ),
        "truth": truth_table(t, scenario.truth),
    }
    return RecordedPass(metadata, tables)
