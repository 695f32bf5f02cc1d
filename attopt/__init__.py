"""attopt: spacecraft attitude determination posed as optimisation problems.

The public API, in one flat namespace (``docs/api.md``):

* the problem's nouns: :class:`Snapshot` (one epoch's measurements of any
  mix of types), :class:`Pass` (epochs of snapshots with a :class:`GyroRecord`,
  :class:`RigidBody` dynamics and a :class:`Prior`);
* gain patterns (:class:`CosinePowerPattern`, :class:`ParabolicPattern`,
  :class:`TabulatedPattern`) and the ADS-B :class:`LinkBudget`;
* measurement types, each with its noise model: :class:`VectorMeasurement`,
  :class:`SnrMeasurement` (of an :class:`SnrEpoch`), :class:`DoaMeasurement`,
  :class:`EulerAngleMeasurement`, :class:`ReferencedMeasurement`; a type of
  your own subclasses :class:`AttitudeMeasurement` and writes its model once
  (:class:`SymbolicModel`), and gets the MAP NLP, the filters and the smoother;
* the estimators, by registry name: :func:`estimator`, :func:`estimators`,
  :data:`ESTIMATORS`, several on one pass with :func:`run_estimators`;
* the results: :class:`Solution` (one epoch) and :class:`Track` (a pass),
  with ``to_dataframe()`` and ``plot()``;
* the bounds: :func:`crb` (one snapshot) and :func:`posterior_bound` (a pass);
* your own recorded passes: :func:`load_pass` and :func:`save_pass`
  (``docs/pass-format.md``);
* the errors every estimator raises instead of returning a wrong attitude.

Example::

    >>> import numpy as np
    >>> import attopt
    >>> snapshot = attopt.Snapshot.from_vectors(
    ...     body=[[1, 0, 0], [0, 1, 0]], reference=[[1, 0, 0], [0, 1, 0]], sigma=1e-3
    ... )
    >>> attopt.estimator("quest").solve(snapshot).valid
    True
"""

from attopt.experiments.recorded import PassFormatError, RecordedPass, load_pass, save_pass
from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    EulerAngleMeasurement,
    ReferencedMeasurement,
    VectorMeasurement,
)
from attopt.formulations.conventions import (
    attitude_error,
    attitude_from_euler321,
    euler321_from_attitude,
)
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.errors import (
    AttoptError,
    ConvergenceError,
    GyroRateMismatchError,
    InvalidObservationError,
    UnobservableError,
    UnsupportedMeasurementError,
)
from attopt.formulations.gain_patterns import CosinePowerPattern, ParabolicPattern, TabulatedPattern
from attopt.formulations.gyro import GYRO_MODELS, MEMS_GYRO, GyroModel, simulate_gyro
from attopt.formulations.link_budget import LinkBudget
from attopt.formulations.measurement_model import SymbolicModel
from attopt.formulations.passes import GyroRecord, Pass, Prior, RigidBody
from attopt.formulations.snapshot import Snapshot, StackedMeasurement
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.bounds import crb, posterior_bound
from attopt.solvers.estimator import Estimator, PassEstimator, SnapshotEstimator
from attopt.solvers.filters import FilterOptions
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.pipeline import Run, run_estimators
from attopt.solvers.registry import ESTIMATORS, UnknownEstimatorError, estimator, estimators
from attopt.solvers.results import Solution, Track
from attopt.solvers.wahba.sdp import SdpOptions

__version__ = "0.1.0"

__all__ = [
    "ESTIMATORS",
    "GYRO_MODELS",
    "MEMS_GYRO",
    "AttitudeMeasurement",
    "AttoptError",
    "ConvergenceError",
    "CosinePowerPattern",
    "DoaMeasurement",
    "Estimator",
    "EulerAngleMeasurement",
    "FilterOptions",
    "GyroModel",
    "GyroRateMismatchError",
    "GyroRecord",
    "InvalidObservationError",
    "LinkBudget",
    "NlpOptions",
    "ParabolicPattern",
    "Pass",
    "PassEstimator",
    "PassFormatError",
    "Prior",
    "RecordedPass",
    "ReferencedMeasurement",
    "RigidBody",
    "Run",
    "SdpOptions",
    "Snapshot",
    "SnapshotEstimator",
    "SnrEpoch",
    "SnrMeasurement",
    "Solution",
    "StackedMeasurement",
    "SymbolicModel",
    "TabulatedPattern",
    "Track",
    "UnknownEstimatorError",
    "UnobservableError",
    "UnsupportedMeasurementError",
    "VectorMeasurement",
    "attitude_error",
    "attitude_from_euler321",
    "crb",
    "estimator",
    "estimators",
    "euler321_from_attitude",
    "load_pass",
    "posterior_bound",
    "run_estimators",
    "save_pass",
    "simulate_gyro",
]
