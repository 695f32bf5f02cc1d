"""The one registry of estimators: every snapshot and pass estimator attopt has.

Experiments, benchmarks, the command line and the contract tests select
estimators by name from here.  Each solver package lists its own in its
``ESTIMATORS``; the registry gathers them in this order.

Example::

    >>> from attopt import SdpOptions, estimator, estimators
    >>> estimators("snapshot")[:6]
    ['triad', 'svd', 'q_method', 'quest', 'foam', 'sdp']
    >>> estimator("sdp", options=SdpOptions(solver="SCS")).options.solver
    'SCS'
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.solvers import doa, filters, geo, map_nlp, smoother, snr, wahba
from attopt.solvers.estimator import Estimator

ESTIMATORS: dict[str, Estimator] = {
    e.name: e
    for package in (wahba, snr, geo, map_nlp, filters, smoother, doa)
    for e in package.ESTIMATORS
}
"""Registry name -> estimator with its default options."""


class UnknownEstimatorError(KeyError):
    """A name that is not in the registry."""

    def __str__(self) -> str:
        return str(self.args[0])


def estimator(name: str, **options: Any) -> Estimator:
    """The registered estimator ``name``, with ``options`` replacing its default fields.

    Raises:
        UnknownEstimatorError: ``name`` is not registered (the message lists the names).
        TypeError: an option that the estimator does not have.

    Example::

        >>> from attopt import FilterOptions, estimator
        >>> gated = estimator("mekf", filter=FilterOptions(gate_probability=0.999))
        >>> gated.filter.gate_probability, estimator("mekf").filter.gate_probability
        (0.999, 0.9999)
    """
    try:
        found = ESTIMATORS[name]
    except KeyError:
        raise UnknownEstimatorError(
            f"unknown estimator {name!r}; registered: {', '.join(ESTIMATORS)}"
        ) from None
    return dataclasses.replace(found, **options) if options else found


def with_options(found: Estimator, options: Mapping[str, Any]) -> Any:
    """``found`` (an estimator or one of its options objects) with ``options`` replacing
    its fields, a table (a mapping) replacing the fields of the options object a field
    holds, recursively: the form a TOML configuration gives
    (``docs/configuration.md``, Estimator options).

    Raises:
        ValueError: a field ``found`` does not have (naming the ones it has), or a table
            for a field that does not hold an options object.

    Example::

        >>> from attopt.solvers.registry import estimator, with_options
        >>> gated = with_options(estimator("mekf"), {"filter": {"gate_probability": 0.999}})
        >>> gated.filter.gate_probability, gated.filter.max_gyro_gap_s
        (0.999, 60.0)
    """
    fields = {f.name for f in dataclasses.fields(found) if f.init} - {"name", "description"}
    unknown = sorted(set(options) - fields)
    if unknown:
        raise ValueError(
            f"{type(found).__name__} has no option {', '.join(unknown)} "
            f"(options: {', '.join(sorted(fields))})"
        )
    changes = {}
    for key, value in options.items():
        current = getattr(found, key)
        if isinstance(value, Mapping):
            if not dataclasses.is_dataclass(current):
                raise ValueError(
                    f"option {key} of {type(found).__name__} takes a value, not a table"
                )
            value = with_options(current, value)
        changes[key] = value
    return dataclasses.replace(found, **changes)


INTEGRITY_TESTS: dict[str, Any] = {
    "consistency_window": 0,
    "mismatch_false_alarm": 0.0,
    "max_variance_factor": 1.0,
    "gyro_exclusions": 0,
    "start_hypotheses": "none",
    "robust_check": False,
}
"""The options fields of the integrity tests and the value that turns each off: the
filters' windowed innovation test
(:func:`attopt.solvers.sequential.inconsistent_epochs`), the snapshot estimators'
residual test (:func:`attopt.solvers.snapshot_sequence.residual_test`), the batch
smoother's covariance scaling by the whole-pass variance factor, which acts on that
test's outcome (:func:`attopt.solvers.smoother.batch.variance_factor`), its gyro
fault test (:func:`attopt.solvers.smoother.batch.gyro_faults`), and the check of Yang
et al. 2014's EKF against its runs from other starts and with Huber-weighted updates
(:mod:`attopt.solvers.start_hypotheses`)."""


def integrity_tests_off(found: Any) -> dict[str, Any]:
    """The options table (the form :func:`with_options` takes) that turns off every
    integrity test of ``found``, an estimator or one of its options objects
    (:data:`INTEGRITY_TESTS`, looked for in its options objects recursively); empty
    when it has none.  With it, an estimate is flagged only by its solver's own checks,
    which measures what the tests cost in accuracy and valid epochs.

    Example::

        >>> from attopt.solvers.registry import estimator, integrity_tests_off
        >>> integrity_tests_off(estimator("mekf")), integrity_tests_off(estimator("quest"))
        ({'filter': {'consistency_window': 0}}, {})
    """
    table: dict[str, Any] = {}
    for field in dataclasses.fields(found):
        value = getattr(found, field.name)
        if field.name in INTEGRITY_TESTS:
            table[field.name] = INTEGRITY_TESTS[field.name]
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            if inner := integrity_tests_off(value):
                table[field.name] = inner
    return table


def estimators(
    kind: str | None = None, accepts: type[AttitudeMeasurement] | None = None
) -> list[str]:
    """Registered names, optionally of one ``kind`` (``"snapshot"`` or ``"pass"``) and
    only those accepting measurement class ``accepts``.

    Example::

        >>> from attopt import SnrMeasurement, estimators
        >>> estimators("snapshot", accepts=SnrMeasurement)
        ['deterministic', 'nlse', 'nlp', 'nlp_truncated', 'geo_cone', 'geo_lsq', 'map_nlp']
    """
    if kind not in (None, "snapshot", "pass"):
        raise ValueError(f"kind must be 'snapshot', 'pass' or None, not {kind!r}")
    return [
        name
        for name, e in ESTIMATORS.items()
        if (kind is None or e.kind == kind)
        and (accepts is None or any(issubclass(accepts, a) for a in e.accepts))
    ]
