"""An experiment's row labels and the registry estimators they name.

Each experiment maps its row labels (``mekf_snr``, ``wahba``,
``ekf_yang2014_q1e-09``, ...) to registry names
(:mod:`attopt.solvers.registry`) in one place; its ``methods`` and ``filters``
parameters are checked here against the labels of the registered estimators
(:func:`registered_labels`), so a name the registry does not have is a
ValueError that lists the ones it has.  Their options come from the
``[estimator_options.NAME]`` tables of :data:`EstimatorOptions`, applied by
:func:`configured` over the experiment's own defaults.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Annotated, Any

from pydantic import AfterValidator, Field

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.solvers import smoother
from attopt.solvers.estimator import Estimator
from attopt.solvers.registry import estimator, estimators, with_options

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


Options = Mapping[str, Mapping[str, Any]]
"""Registry name -> the options that replace its defaults (a TOML table per estimator)."""


def _checked_options(options: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    for name, table in options.items():
        try:
            with_options(estimator(name), table)
        except (KeyError, ValueError, TypeError) as error:
            raise ValueError(f"{name}: {error}") from None
    return options


EstimatorOptions = Annotated[
    dict[str, dict[str, Any]],
    AfterValidator(_checked_options),
    Field(
        default_factory=dict,
        description=(
            "Options of the registry's estimators, by registry name, replacing their "
            "defaults: a value per field, a table per options object (e.g. "
            "[estimator_options.mekf.filter] gate_probability = 0.999; docs/api.md lists them)."
        ),
    ),
]
"""The ``estimator_options`` parameter of every experiment: ``[estimator_options.NAME]``
tables, each checked by building the estimator with it."""


def configured(name: str, options: Options, **defaults: Any) -> Estimator:
    """Registry estimator ``name`` with the experiment's ``defaults``, then ``options``'
    table for ``name`` (:func:`~attopt.solvers.registry.with_options`).

    Example::

        >>> from attopt.experiments.estimators import configured
        >>> configured("nlp", {"nlp": {"options": {"max_iter": 50}}}).options.max_iter
        50
    """
    return with_options(estimator(name, **defaults), options.get(name, {}))


def configured_all(
    labels: Mapping[str, str], options: Options, defaults: Options | None = None
) -> dict[str, Estimator]:
    """Row label -> :func:`configured` estimator of each registry name of ``labels``, with
    the experiment's ``defaults`` for it (by registry name)."""
    defaults = defaults or {}
    return {
        label: configured(name, options, **defaults.get(name, {})) for label, name in labels.items()
    }
