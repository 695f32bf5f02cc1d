"""Names of the experiments the CLI can run, imported only when requested.

``EXPERIMENTS`` maps a short name to the import path ``"package.module:OBJECT"``
of a module-level :class:`~attopt.experiments.experiment.Experiment`.  Modules are
imported lazily, so a registered module that is missing or broken only fails
when that experiment is requested.  Anywhere a name is accepted, an import
path is accepted as well (e.g. for experiments kept outside this package).
"""

from __future__ import annotations

import importlib
import sys

from attopt.experiments.experiment import Experiment

EXPERIMENTS: dict[str, str] = {
    "noop": "attopt.experiments.sweep.toys:NOOP",
    "wahba-mag-sun": "attopt.experiments.wahba_mag_sun.experiment:EXPERIMENT",
    "adsb-snr": "attopt.experiments.adsb_snr.experiment:EXPERIMENT",
    "adsb-sky": "attopt.experiments.adsb_sky.experiment:EXPERIMENT",
    "doa-ground": "attopt.experiments.doa_ground.experiment:EXPERIMENT",
    "geo-snr-stations": "attopt.experiments.geo_snr_stations.experiment:EXPERIMENT",
}


class UnknownExperimentError(ValueError):
    """The requested experiment is neither a registered name nor an import path."""


def get_experiment(name: str) -> Experiment:
    """Return the experiment registered as ``name`` or found at import path ``name``.

    Raises :class:`UnknownExperimentError` listing the known names when ``name``
    is neither, and :class:`TypeError` when the path names something else.
    """
    path = EXPERIMENTS.get(name)
    if path is None:
        if ":" not in name:
            known = ", ".join(sorted(EXPERIMENTS)) or "(none)"
            raise UnknownExperimentError(
                f"unknown experiment {name!r}; known experiments: {known} "
                "(or give an import path 'package.module:OBJECT')"
            )
        path = name
    module_name, _, attribute = path.partition(":")
    module = importlib.import_module(module_name)
    try:
        experiment = getattr(module, attribute)
    except AttributeError:
        raise UnknownExperimentError(f"module {module_name!r} has no {attribute!r}") from None
    if not isinstance(experiment, Experiment):
        raise TypeError(f"{path} is a {type(experiment).__name__}, not an Experiment")
    return experiment


def list_experiments() -> list[tuple[str, str]]:
    """Return ``(name, one-line summary)`` for every registered experiment.

    An experiment whose module cannot be imported is listed with the error in
    place of its summary.
    """
    listing = []
    for name in sorted(EXPERIMENTS):
        try:
            summary = get_experiment(name).summary.strip().splitlines()[0]
        except Exception as error:
            summary = f"(cannot be loaded: {type(error).__name__}: {error})"
        listing.append((name, summary))
    return listing


def reference_of(experiment: Experiment) -> str:
    """Return an import path ``"module:OBJECT"`` under which ``experiment`` is found.

    Worker processes import the experiment from this path instead of receiving
    it pickled, so it must be a module-level object of an importable module.
    """
    candidates = [experiment.trial.__module__, experiment.grid.__module__]
    registered = EXPERIMENTS.get(experiment.name)
    if registered is not None:
        candidates.append(registered.partition(":")[0])
    for module_name in dict.fromkeys(candidates):
        module = sys.modules.get(module_name)
        if module is None:
            continue
        for attribute, value in vars(module).items():
            if value is experiment:
                return f"{module_name}:{attribute}"
    raise ValueError(
        f"experiment {experiment.name!r} is not a module-level object of the module "
        f"defining its trial function ({experiment.trial.__module__}); worker processes "
        "import experiments by path, so define it at module level"
    )


def display_name(reference: str) -> str:
    """Return the registered name whose import path is ``reference``, else ``reference``."""
    for name, path in EXPERIMENTS.items():
        if path == reference:
            return name
    return reference
