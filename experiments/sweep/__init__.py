"""Monte Carlo sweeps of experiments: seeding, engines, storage with resume, summary.

``run_sweep`` expands an :class:`~experiments.experiment.Experiment` into
settings x trials, executes them in this process, a local process pool or on a
Dask cluster, writes finished chunks to the output directory as they arrive
(rerunning resumes), and writes ``summary.csv``, ``failures.csv`` and
``report.md``.  See ``docs/sweeps.md``.
"""

from experiments.sweep.aggregate import summarise
from experiments.sweep.config import ConfigError, load_config, resolve_parameters
from experiments.sweep.engines import EngineSetupError
from experiments.sweep.runner import SweepResult, run_sweep
from experiments.sweep.seeding import trial_seed
from experiments.sweep.store import ManifestMismatchError

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
