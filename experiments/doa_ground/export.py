"""A simulated ``doa-ground`` pass as a recorded pass (:mod:`attopt.experiments.recorded`).

:func:`export` lays out what :func:`~attopt.experiments.doa_ground.experiment.trial`
simulates for ``(setting, seed)``, with the experiment's own functions, as an
orbit-frame pass (``attitude_frame = "orbit"``):

* ``vectors``: the unit vectors of MUSIC's accepted DOAs (Yang et al. 2014 eq. 12)
  against the orbit-frame lines of sight to the stations (eq. 17), with their
  isotropic sigmas, one row per accepted ``(epoch, station)``, ``sensor`` the
  station's name (:func:`~attopt.experiments.doa_ground.experiment.simulate_pass`);
* ``epochs``: every epoch, also those without an accepted DOA (the estimators
  propagate through them);
* ``position``: the satellite's ECI position and velocity at the epochs
  (:func:`~attopt.experiments.doa_ground.scenario.orbit_track`), whose orbit frames
  (:func:`~attopt.formulations.conventions.orbit_frame_attitude`) are the
  scenario's ``A_oi`` bit for bit;
* ``[dynamics]``: the rigid body's inertia and wheel momentum (eqs. 23-25);
* ``truth``: the true orbit -> body attitude ``C_bo``;
* ``gyro`` and ``[gyro]``, when the setting has gyro-aided ``filters``: the
  record of the gyro-aided rows, sampled at the epochs, from the trial's gyro
  stream (:func:`~attopt.experiments.doa_ground.experiment.gyro_inputs`; drawn
  for every trial, though the trial runs those rows in its first
  ``filter_trials`` trials only);
* two priors (``[[prior]]``): the ``[prior]`` parameters' orbit-frame estimate
  with its body rate (Yang et al. 2014 sec. 6), which the estimators on rigid-body
  dynamics start from, and, with a gyro, the same estimate in ECI with a zero
  bias and the gyro's bias sigma, which the gyro-aided ones start from.

There is no ``doa`` table: the trial's estimators consume the unit vectors, and
a ``doa`` table would add a DOA measurement of the same stations to each epoch.

``attopt estimate`` on the exported pass runs registry estimators with their
default options, each from the start it finds among those asked for, so it
reproduces the trial's rows (at the rows' epochs, every ``row_step_s``) of

* ``ekf_yang2014`` and ``rts_yang2014`` (estimated together): the rows
  ``ekf_yang2014_q1e-09`` and ``rts_yang2014_q1e-09``, the registry's default
  ``Q = 1e-9 E_6`` (Yang et al. 2014's); the rows of another ``process_noise``
  need an option ``attopt estimate`` does not pass;
* the gyro-aided filters that start from the prior: ``mekf``, ``usque``, and
  ``rts`` estimated together with ``mekf``.

It does not reproduce ``bls_yang2014`` and the smoothers ``fg_batch`` and
``fg_batch_offsets`` (the trial starts them from the lowest-``Q`` RTS pass,
``bls_yang2014`` with unconverged estimates kept), nor the ``wahba`` rows (the
trial's vectorised SVD at the row epochs only), nor the bounds ``pbound_*``,
``crb_*`` and ``bound_*`` and the ``music`` row.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from astropy.time import Time

from attopt.experiments.doa_ground.experiment import gyro_inputs, simulate_pass
from attopt.experiments.doa_ground.scenario import orbit_track
from attopt.experiments.experiment import Setting
from attopt.experiments.recorded.metadata import (
    INERTIAL,
    ORBIT,
    DynamicsEntry,
    PassMetadata,
    gyro_entry,
)
from attopt.experiments.recorded.recorded_pass import RecordedPass
from attopt.experiments.recorded.records import (
    gyro_table,
    position_table,
    prior_entry,
    truth_table,
    vector_table,
)


def export(setting: Setting, seed: np.random.SeedSequence) -> RecordedPass:
    """Trial ``seed`` of ``setting`` as a :class:`RecordedPass` (module docstring).

    Example::

        >>> import numpy as np
        >>> from attopt.experiments.doa_ground.experiment import EXPERIMENT
        >>> from attopt.experiments.doa_ground.export import export
        >>> parameters = {**EXPERIMENT.parameters, "duration_s": 30.0, "step_s": 1.0}
        >>> setting = EXPERIMENT.grid(parameters)[0]
        >>> recorded = export(setting, np.random.SeedSequence(0))
        >>> recorded
        RecordedPass(attitude orbit, Pass(30 epochs, t 0-29 s, 11 with measurements,
                     rigid-body dynamics, prior), tables epochs, gyro, vectors, position, truth)
        >>> [prior.frame for prior in recorded.metadata.prior]
        ['orbit', 'eci']
    """
    simulated = simulate_pass(setting, seed)
    parameters, geometry = simulated.parameters, simulated.geometry
    scenario = parameters.scenario()
    orbit = orbit_track(
        scenario.orbit.tle(), scenario.start_utc, scenario.duration_s, scenario.step_s
    )
    body, reference, sigma = simulated.vectors
    stations = [station.name for station in parameters.stations]
    priors = [prior_entry(simulated.pass_.prior, ORBIT)]
    tables = {
        "epochs": pd.DataFrame({"t_s": geometry.t}),
        "vectors": vector_table(geometry.t, stations, body, reference, sigma),
        "position": position_table(geometry.t, orbit.position_eci_km, orbit.velocity_eci_kms),
        "truth": truth_table(geometry.t, geometry.truth),
    }
    gyro = None
    if parameters.filters:
        _, inputs = gyro_inputs(parameters, seed, geometry)
        tables["gyro"] = gyro_table(inputs.record)
        gyro = gyro_entry(inputs.model)
        priors.append(prior_entry(inputs.prior, INERTIAL))
    metadata = PassMetadata(
        description=(
            f"doa-ground: a simulated pass of Yang et al. 2014's DOA attitude scenario at "
            f"input SNR {setting['snr_db']:g} dB, L = {setting['snapshots']} snapshots"
        ),
        start_utc=Time(scenario.start_utc, scale="utc").isot,
        attitude_frame=ORBIT,
        position_frame=INERTIAL,
        gyro=gyro,
        prior=tuple(priors),
        dynamics=DynamicsEntry(
            inertia_kg_m2=tuple(tuple(row) for row in geometry.dynamics.inertia.tolist()),
            wheel_momentum_n_m_s=tuple(np.asarray(geometry.dynamics.wheel_momentum).tolist()),
        ),
    )
    return RecordedPass(metadata, tables)
