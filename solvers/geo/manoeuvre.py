"""Manoeuvre detection from a filter's innovations and re-initialisation from the boresight.

Pimienta-Penalver and Crassidis sec. V.B, Fig. 10: the unscented filter is given the
broadcaster's *assumed* body rate; an unannounced 25 deg manoeuvre makes that rate wrong and
the filter "breaks", which the paper proposes as a way to sense the manoeuvre,
leaving the restart to the user.  Here both steps are automatic.

Detection: a windowed chi-square test on the normalised innovation squared
(NIS) the filters record per epoch (the track's ``loss`` = diagnostic ``nis``,
``nu^T P_nunu^-1 nu`` over the epoch's used rows, :mod:`attopt.solvers.filters.usque`).
For a consistent filter the NIS of epoch ``k`` is chi-square with ``n_k``
degrees of freedom (``n_k`` = ``n_used``: one per SNR, whose blocks are
scalars) and independent between epochs, so over the last ``W`` epochs::

    S_k = sum_{j = k - W + 1}^{k} NIS_j  ~  chi2(sum_j n_j),

and a manoeuvre is declared at the first ``k`` with ``P(chi2 >= S_k) <
p_FA`` (:attr:`DetectionOptions.false_alarm`, per window).  The filter is run
without its innovation gate (``gate_probability = 1``, as the paper's filter):
a gate would drop exactly the rows that carry the evidence.

Re-initialisation at the detection epoch ``k_d``: the snapshot boresight
``B`` of that epoch (cone intersection or least squares, sec. IV.B,
:mod:`attopt.solvers.geo.boresight`) fixes roll and pitch.  Yaw about the boresight
is unobservable from SNRs (every row of the SNR Jacobian is orthogonal to the
boresight, ``docs/geo.md``): the filter's estimate from before the failing
window, carried to ``k_d`` with the assumed rates, keeps its yaw and is turned
by the smallest rotation that moves its boresight onto ``B``
(:func:`boresight_prior`); the prior covariance is
``sigma_B^2`` about the two axes across the boresight and a large
``sigma_yaw^2`` about it.  After a manoeuvre the assumed rate is wrong by a
roughly constant body rate, which the bias state absorbs: its prior sigma is
reset to :attr:`DetectionOptions.bias_sigma`.  The filter (the registry's
``usque``) is then restarted on the rest of the pass, from the last gyro
sample at or before ``k_d`` (``k_d`` itself when the epochs are sample times),
and the test resumes once a whole window lies after the restart.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.geo_link import BORESIGHT_BODY
from attopt.formulations.passes import GyroRecord, Pass, Prior
from attopt.solvers.chi_square import chi_square_tail
from attopt.solvers.filters import FilterOptions, Usque
from attopt.solvers.filters.common import propagate_attitude
from attopt.solvers.gyro_timeline import COINCIDENCE, gyro_timeline
from attopt.solvers.results import Track

Array = NDArray[np.float64]


@dataclass(frozen=True)
class DetectionOptions:
    """Test and restart settings (module docstring).

    Attributes:
        window: ``W``, epochs summed in the chi-square test.
        false_alarm: ``p_FA`` per window.
        boresight_sigma: ``sigma_B`` (rad) of the snapshot boresight, per axis across it.
        yaw_sigma: ``sigma_yaw`` (rad) about the boresight (unobservable).
        bias_sigma: prior sigma (rad/s) of the rate-error (bias) state after a restart.
        max_restarts: at most this many re-initialisations per pass.
    """

    window: int = 3
    false_alarm: float = 1e-6
    boresight_sigma: float = np.radians(0.02)
    yaw_sigma: float = np.radians(20.0)
    bias_sigma: float = np.radians(20.0) / 3600.0
    max_restarts: int = 3

    def __post_init__(self) -> None:
        if self.window < 1 or not 0.0 < self.false_alarm < 1.0 or self.max_restarts < 0:
            raise InvalidObservationError(f"bad detection options: {self}")


def windowed_nis_test(nis: ArrayLike, dof: ArrayLike, window: int, false_alarm: float) -> Array:
    """``P(chi2(sum n) >= S_k)`` of the window ending at each epoch (NaN before a full window).

    Epochs without an update (NaN NIS) add nothing to ``S_k`` nor to the
    degrees of freedom.
    """
    nis = np.asarray(nis, dtype=float)
    used = np.isfinite(nis)
    s = np.convolve(np.where(used, nis, 0.0), np.ones(window), mode="valid")
    n = np.convolve(np.where(used, np.asarray(dof, dtype=float), 0.0), np.ones(window), "valid")
    p = np.full(nis.size, np.nan)
    p[window - 1 :] = np.where(n > 0, chi_square_tail(s, np.maximum(n, 1.0)), np.nan)
    return p


def first_detection(result: Track, options: DetectionOptions, start: int = 0) -> int | None:
    """First epoch ``k >= start + W - 1`` whose window fails the test, else ``None``."""
    diagnostics = result.diagnostics
    p = windowed_nis_test(
        diagnostics["nis"], diagnostics["n_used"], options.window, options.false_alarm
    )
    p[: start + options.window - 1] = np.nan
    hits = np.flatnonzero(p < options.false_alarm)
    return int(hits[0]) if hits.size else None


def boresight_prior(
    reference: Rotation,
    boresight: ArrayLike,
    bias: ArrayLike,
    options: DetectionOptions,
) -> Prior:
    """``reference`` (ECI -> body) turned so that its boresight is ``boresight`` (module docstring).

    The smallest rotation ``Q`` (reference frame) taking ``A^T z`` to ``B``
    gives ``A' = A Q^T``, so ``A'^T z = B`` with the yaw of ``A``.
    """
    b = np.asarray(boresight, dtype=float)
    if b.shape != (3,) or not np.all(np.isfinite(b)) or not np.any(b):
        raise InvalidObservationError(f"boresight must be a finite non-zero 3-vector, got {b}")
    current = reference.inv().apply(BORESIGHT_BODY)
    turn, _ = Rotation.align_vectors((b / np.linalg.norm(b))[None], current[None])
    across = options.boresight_sigma**2
    attitude_cov = across * np.eye(3) + (options.yaw_sigma**2 - across) * np.outer(
        BORESIGHT_BODY, BORESIGHT_BODY
    )
    covariance = np.zeros((6, 6))
    covariance[:3, :3] = attitude_cov
    covariance[3:, 3:] = options.bias_sigma**2 * np.eye(3)
    return Prior(reference * turn.inv(), covariance, bias=np.asarray(bias, dtype=float))


@dataclass(frozen=True)
class ManoeuvreRun:
    """A filter pass with automatic restarts.

    Attributes:
        result: the spliced estimates (each restart's run from its epoch on).
        detections: epochs at which a manoeuvre was declared (and the filter restarted).
        p_value: the windowed test's ``P(chi2 >= S_k)`` per epoch of the spliced pass.
    """

    result: Track
    detections: tuple[int, ...]
    p_value: Array


def _splice(head: Track, tail: Track, k: int) -> Track:
    """Epochs ``< k`` of ``head`` followed by ``tail`` (whose epoch 0 is ``k``)."""

    def join(a: Array, b: Array) -> Array:
        return np.concatenate([a[:k], b])

    return dataclasses.replace(
        head,
        quaternion=join(head.quaternion, tail.quaternion),
        covariance=join(head.covariance, tail.covariance),
        loss=join(head.loss, tail.loss),
        valid=join(head.valid, tail.valid),
        reason=join(head.reason, tail.reason),
        error=join(head.error, tail.error),
        diagnostics={
            name: join(head.diagnostics[name], tail.diagnostics[name]) for name in head.diagnostics
        },
        t=join(head.t, tail.t),
        bias=join(head.bias, tail.bias),
        state_covariance=join(head.state_covariance, tail.state_covariance),
    )


def detect_and_reinitialise(
    pass_: Pass,
    boresight: Callable[[int], Array],
    options: DetectionOptions | None = None,
    filter_options: FilterOptions | None = None,
    method: str = "usque_detect",
) -> ManoeuvreRun:
    """USQUE over the pass, restarted at each detected manoeuvre (module docstring).

    ``pass_`` has the (assumed-rate) gyro record and the prior;
    ``boresight(k)``: the snapshot boresight (reference frame) of epoch ``k``.
    ``filter_options`` are used with the gate off.  No restart is made (and
    the search stops) when the estimate before the failing window is invalid,
    or when no gyro step is left after the restart's sample.
    """
    options = options or DetectionOptions()
    faults = dataclasses.replace(filter_options or FilterOptions(), gate_probability=1.0)
    usque = Usque(filter=faults)
    gyro = pass_.gyro
    if gyro is None:
        raise InvalidObservationError("manoeuvre detection runs USQUE: the pass needs a gyro")
    timeline = gyro_timeline(gyro.samples, pass_.t)
    result = usque.solve(pass_)
    detections: list[int] = []
    start = 0
    while len(detections) < options.max_restarts:
        k = first_detection(result, options, start)
        if k is None:
            break
        before = max(k - options.window, start)
        # the last gyro sample at or before epoch k, and its place in the timeline
        sample = int(np.searchsorted(gyro.t, pass_.t[k] + COINCIDENCE * gyro.model.dt, "right"))
        sample -= 1
        if not result.valid[before] or sample >= gyro.t.size - 1:
            break
        node = int(np.searchsorted(timeline.t, gyro.t[sample]))
        steps = slice(timeline.epochs[before], node)
        bias = result.bias[before]
        reference = propagate_attitude(
            Rotation.from_quat(result.quaternion[before]),
            timeline.rates[steps] - bias,
            timeline.dt[steps],
        )
        tail = Pass(
            pass_.t[k:],
            pass_.snapshots[k:],
            GyroRecord(gyro.t[sample:], gyro.rates[sample:], gyro.model),
            boresight_prior(reference, boresight(k), bias, options),
        )
        result = _splice(result, usque.solve(tail), k)
        detections.append(k)
        start = k
    diagnostics = result.diagnostics
    p = windowed_nis_test(
        diagnostics["nis"], diagnostics["n_used"], options.window, options.false_alarm
    )
    return ManoeuvreRun(dataclasses.replace(result, method=method), tuple(detections), p)
