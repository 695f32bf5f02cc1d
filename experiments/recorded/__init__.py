"""Recorded passes: a documented on-disk format for your own data (``docs/pass-format.md``).

A pass directory holds ``pass.toml`` (frames, gyro model, SNR antennas and link,
DOA array, priors, dynamics) and one parquet or CSV file per table (gyro
samples, vector, SNR and DOA observations, the satellite's position, the
truth).  :func:`load_pass` checks it and builds the library
:class:`~attopt.formulations.passes.Pass` (:class:`RecordedPass`);
:func:`save_pass` writes one; :mod:`~attopt.experiments.recorded.estimate`
runs registered estimators on it (``attopt estimate``) and writes rows,
summary, report and figures as an experiment does; an experiment's
``export`` module turns one of its simulated passes into a
:class:`RecordedPass` (:mod:`~attopt.experiments.recorded.export`).
"""

from attopt.experiments.recorded.errors import PassFormatError
from attopt.experiments.recorded.metadata import PassMetadata
from attopt.experiments.recorded.recorded_pass import RecordedPass, load_pass, save_pass

__all__ = ["PassFormatError", "PassMetadata", "RecordedPass", "load_pass", "save_pass"]
