"""Each experiment's export of a simulated pass as a :class:`RecordedPass`.

An experiment that can export its passes has a module ``export`` in its
package with one function, ``export(setting, seed) -> RecordedPass``
(:class:`PassExport`): the pass that ``trial(setting, seed)`` simulates, with
exactly the arrays its estimators consume, its truth and its prior, so that
estimating the exported pass (saved and loaded, or not) gives the trial's
estimates bit for bit.  :func:`exporter` finds it by the experiment's name.
"""

from __future__ import annotations

import importlib
from typing import Protocol

import numpy as np

from attopt.experiments.experiment import Setting
from attopt.experiments.recorded.recorded_pass import RecordedPass
from attopt.experiments.registry import get_experiment


class PassExport(Protocol):
    """``export(setting, seed)``: trial ``seed`` of ``setting`` as a recorded pass."""

    def __call__(self, setting: Setting, seed: np.random.SeedSequence) -> RecordedPass: ...


def exporter(name: str) -> PassExport:
    """The ``export`` function of experiment ``name`` (a registered name or import path).

    Raises:
        ValueError: the experiment's package has no ``export`` module.

    Example::

        >>> from attopt.experiments.recorded.export import exporter
        >>> exporter("wahba-mag-sun").__module__
        'attopt.experiments.wahba_mag_sun.export'
    """
    package = get_experiment(name).trial.__module__.rpartition(".")[0]
    try:
        module = importlib.import_module(f"{package}.export")
    except ModuleNotFoundError:
        raise ValueError(
            f"experiment {name!r} cannot export its passes (no {package}.export)"
        ) from None
    return module.export
