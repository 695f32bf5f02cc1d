"""Monte Carlo sweeps of experiments: seeding, engines, storage with resume, summary.

``run_sweep`` expands an :class:`~attopt.experiments.experiment.Experiment` into
settings x trials, executes them in this process, a local process pool or on a
Dask cluster, writes finished chunks to the output directory as they arrive
(rerunning resumes), and writes ``summary.csv``, ``failures.csv`` and
``report.md``.  See ``docs/sweeps.md``.
"""

from attopt.experiments.config import ConfigError, load_config, resolve_parameters
from attopt.experiments.sweep.aggregate import summarise
from attopt.experiments.sweep.engines import EngineSetupError
from attopt.experiments.sweep.runner import SweepResult, run_sweep
from attopt.experiments.sweep.seeding import trial_seed
from attopt.experiments.sweep.store import ManifestMismatchError

__all__ = [
    "ConfigError",
    "EngineSetupError",
    "ManifestMismatchError",
    "SweepResult",
    "load_config",
    "resolve_parameters",
    "run_sweep",
    "summarise",
    "trial_seed",
]
