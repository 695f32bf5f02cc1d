"""A simulated ``wahba-mag-sun`` pass as a recorded pass (:mod:`attopt.experiments.recorded`).

:func:`export` lays out what :func:`~attopt.experiments.wahba_mag_sun.experiment.trial`
simulates for ``(setting, seed)``, with the experiment's own functions: the
Sun and field directions with their orbit-frame references
(:func:`~attopt.experiments.wahba_mag_sun.experiment.simulate_pass`; no Sun
row in eclipse), the gyro record and the prior of the gyro-aided estimators
(:func:`~attopt.experiments.wahba_mag_sun.experiment.filter_inputs`, from the
trial's gyro stream), the satellite's ECI position and velocity (the orbit
frames the filters' measurements are re-expressed with) and the true
orbit -> body attitude.
"""

from __future__ import annotations

import numpy as np

from attopt.experiments.experiment import Setting
from attopt.experiments.recorded.metadata import INERTIAL, ORBIT, PassMetadata, gyro_entry
from attopt.experiments.recorded.recorded_pass import RecordedPass
from attopt.experiments.recorded.records import (
    gyro_table,
    position_table,
    prior_entry,
    truth_table,
    vector_table,
)
from attopt.experiments.wahba_mag_sun.experiment import (
    WahbaMagSunParameters,
    filter_inputs,
    geometry_of,
    simulate_pass,
)

SENSORS = ("sun", "magnetometer")
"""The sensors of the ``vectors`` table, in the experiment's order."""


def export(setting: Setting, seed: np.random.SeedSequence) -> RecordedPass:
    """Trial ``seed`` of ``setting`` as a :class:`RecordedPass` (module docstring).

    Example::

        >>> import numpy as np
        >>> from attopt.experiments.wahba_mag_sun.experiment import EXPERIMENT
        >>> from attopt.experiments.wahba_mag_sun.export import export
        >>> setting = {**EXPERIMENT.parameters, "duration_s": 60.0}
        >>> export(setting, np.random.SeedSequence(0))
        RecordedPass(attitude orbit, Pass(60 epochs, t 0-59 s, 60 with measurements),
                     tables gyro, vectors, position, truth)
    """
    parameters = WahbaMagSunParameters.model_validate(setting)
    geometry = geometry_of(parameters)
    vectors = simulate_pass(geometry, seed, parameters)
    _, inputs = filter_inputs(parameters, seed)
    metadata = PassMetadata(
        description="wahba-mag-sun: a simulated pass of TIMED (Cilden Guler et al. 2017)",
        start_utc=geometry.start_utc,
        attitude_frame=ORBIT,
        position_frame=INERTIAL,
        gyro=gyro_entry(inputs.model),
        prior=prior_entry(inputs.prior, INERTIAL),
    )
    tables = {
        "gyro": gyro_table(inputs.record),
        "vectors": vector_table(
            geometry.t, SENSORS, vectors.body, vectors.reference, vectors.sigma
        ),
        "position": position_table(geometry.t, geometry.position_eci_km, geometry.velocity_eci_kms),
        "truth": truth_table(geometry.t, geometry.truth),
    }
    return RecordedPass(metadata, tables)
