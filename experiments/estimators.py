"""An experiment's row labels and the registry estimators they name.

Each experiment maps its row labels (``mekf_snr``, ``wahba``,
``ekf_yang2014_q1e-09``, ...) to registry names
(:mod:`attopt.solvers.registry`) in one place; its ``methods`` and ``filters``
parameters are checked here against the labels of the registered estimators
(:func:`registered_labels`), so a name the registry does not have is a
ValueError that lists the ones it has.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Annotated, Any

from pydantic import AfterValidator

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.solvers import smoother
from attopt.solvers.registry import estimators

FACTOR_GRAPH = frozenset(e.name for e in smoother.ESTIMATORS)
"""The factor-graph smoothers of the registry: with one of them on a pass, its rows also
carry the posterior bound (:func:`attopt.experiments.metrics.posterior_bound_columns`,
whose cost is about one smoother pass)."""


def registered_labels(
    kind: str,
    accepts: type[AttitudeMeasurement],
    label: Callable[[str], str] = str,
) -> dict[str, str]:
    """Row label -> registry name of every registered estimator of ``kind`` that accepts
    ``accepts``, labelled by ``label`` (by default its registry name)."""
    return {label(name): name for name in estimators(kind, accepts)}


def resolve(requested: Iterable[str], labels: Mapping[str, str], what: str) -> dict[str, str]:
    """Row label -> registry name of each ``requested`` label.

    Raises:
        ValueError: a label not in ``labels``, naming the known ones with their
            registry names.
    """
    requested = list(requested)
    unknown = [name for name in requested if name not in labels]
    if unknown:
        known = ", ".join(k if k == v else f"{k} ({v})" for k, v in labels.items())
        raise ValueError(f"unknown {what} {unknown}; registered: {known}")
    return {name: labels[name] for name in requested}


def label_field(labels: Callable[[], Mapping[str, str]], what: str) -> Any:
    """The pydantic type of one row label among ``labels()``, for an experiment's
    ``methods`` or ``filters`` parameter: a config naming another is an error that lists
    the registered ones (:func:`resolve`).

    Example::

        >>> from pydantic import TypeAdapter
        >>> from attopt import VectorMeasurement
        >>> labels = lambda: registered_labels("snapshot", VectorMeasurement)
        >>> TypeAdapter(list[label_field(labels, "method")]).validate_python(["quest"])
        ['quest']
    """

    def check(label: str) -> str:
        resolve([label], labels(), what)
        return label

    return Annotated[str, AfterValidator(check)]
