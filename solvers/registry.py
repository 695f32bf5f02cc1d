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
