"""SNRs of one epoch as an :class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement`.

Each received message's SNR is a scalar measurement (Liu et al. 2023 eqs. 4, 13):
the model ``f_k(A)`` of :func:`attopt.formulations.snr_model.snr_db`, with its
Jacobian with respect to the body-frame attitude error by CasADi AD
(:func:`~attopt.formulations.snr_model.predict_snr`).  Filtering with the SNRs
themselves is Liu et al. 2023's proposed future work (sec. 6).

Two measurement models:

* ``truncated=False``: ``y_k = f_k(A) + nu_k``, ``nu_k ~ N(0, sigma_k^2)``,
  the Gaussian model of Liu et al. 2023 eq. 19;
* ``truncated=True``: a message is received only when ``y_k >= tau`` (Liu et
  al. 2023 sec. 5.1, :mod:`attopt.formulations.snr_truncation`), so the received ``y_k``
  has mean ``f_k + sigma lambda(x_k)`` and variance ``sigma^2 (1 - x_k
  lambda - lambda^2)``, ``x_k = (f_k - tau) / sigma``, ``lambda`` the inverse
  Mills ratio.  Those two moments are the filter's measurement model (the
  prediction and an attitude-dependent ``R``,
  :meth:`SnrMeasurement.noise_covariance_at`); the Jacobian of the mean is
  AD of the same symbolic expression.  Without it a filter, which averages
  many epochs, integrates the selection bias of near-threshold messages
  (+0.18 dB on average in ``adsb-snr``) into a systematic attitude error.

The gain pattern is defined in the main lobe only: an observation whose
off-boresight angle at a predicted attitude lies beyond it cannot be
predicted and is returned as NaN (the filters leave it out and count it).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import Array, AttitudeMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.kernels import evaluate_mapped
from attopt.formulations.measurement_model import SymbolicModel
from attopt.formulations.snr_model import (
    Pattern,
    pattern_snr_model,
    predict_snr,
    snr_db_or_nan,
)
from attopt.formulations.snr_problem import SnrEpoch
from attopt.formulations.snr_truncation import inverse_mills_ratio, truncated_information_factor
from attopt.formulations.symbolic import CASADI


@lru_cache(maxsize=16)
def truncated_mean_model(pattern: Pattern, sigma_db: float, threshold_db: float) -> Callable:
    """``E[y | y >= tau] = f + sigma lambda((f - tau) / sigma)`` of :func:`snr_db` (symbolic;
    the arguments of :func:`~attopt.formulations.snr_model.pattern_snr_model`)."""
    snr_model = pattern_snr_model(pattern)

    def truncated_snr(attitude: Any, *data: Any) -> Any:
        f = snr_model(attitude, *data)
        return f + sigma_db * inverse_mills_ratio((f - threshold_db) / sigma_db)

    return truncated_snr


@lru_cache(maxsize=16)
@lru_cache(maxsize=64)
def truncated_mean_slope(sigma_db: float, threshold_db: float) -> ca.Function:
    """``d E[y | y >= tau] / d f`` by CasADi AD (scalar function; maps over a row of ``f``),
    built once per ``(sigma_db, threshold_db)`` (its kernel is then compiled once,
    :func:`~attopt.formulations.kernels.evaluate_mapped`).

    It equals :func:`~attopt.formulations.snr_truncation.truncated_information_factor`
    (the truncated variance over ``sigma^2``), an identity the tests check.
    """
    f = ca.SX.sym("f")
    mean = f + sigma_db * inverse_mills_ratio((f - threshold_db) / sigma_db, CASADI)
    return ca.Function("truncated_mean_slope", [f], [ca.jacobian(mean, f)])


def _truncated_slope(f: Array, noise: Array, group: NDArray[np.intp]) -> Array:
    """:func:`truncated_mean_slope` at the untruncated SNRs ``f`` (NaN where ``f`` is), each
    row with the ``(sigma, threshold)`` of ``noise`` ``(k, 2)`` that ``group`` ``(rows,)``
    names: one kernel call per pair."""
    out = np.full(f.shape, np.nan)
    usable = np.isfinite(f)
    for i, (sigma, threshold) in enumerate(noise):
        rows = usable & (group == i)
        if rows.any():
            slope = truncated_mean_slope(float(sigma), float(threshold))
            out[rows] = evaluate_mapped(slope, f[rows, None])[0].ravel()
    return out


class SnrMeasurement(AttitudeMeasurement):
    """The SNRs of ``epoch`` (orbit-frame lines of sight: the attitude is orbit -> body).

    ``truncated=True`` uses the moments of the threshold-truncated measurement
    (module docstring); it needs one standard deviation for the whole epoch.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import CosinePowerPattern, LinkBudget, SnrEpoch, SnrMeasurement
        >>> helix = CosinePowerPattern(peak_gain=14.46, exponent=6.0, min_gain_dbi=4.0)
        >>> epoch = SnrEpoch.from_ranges(
        ...     [12.0, 10.0], [[0.0, 0.0, 1.0], [0.1, 0.0, 0.995]], [0, 0], [[0.0, 0.0, 1.0]],
        ...     [1.2e6, 1.5e6], helix, LinkBudget(),
        ... )
        >>> SnrMeasurement(epoch).predict(Rotation.identity())[0].round(2).tolist()  # dB
        [[15.26, 13.19]]
    """

    def __init__(self, epoch: SnrEpoch, truncated: bool = False) -> None:
        self.epoch = epoch
        self.truncated = truncated
        self.z = epoch.snr_db
        sigma = np.broadcast_to(epoch.sigma_db, (epoch.m,))
        self.noise_covariance = sigma**2
        self.blocks = np.arange(epoch.m)
        self.sources = epoch.transmitter
        self._model = None
        if truncated:
            if epoch.m and np.ptp(sigma) > 0:
                raise InvalidObservationError("the truncated SNR model needs one sigma per epoch")
            self.sigma = float(sigma[0]) if epoch.m else 1.0
            self._model = truncated_mean_model(epoch.pattern, self.sigma, epoch.threshold_db)

    def _snr(self, matrices: Array) -> Array:
        """Untruncated ``f`` ``(N, m)`` (numpy) at the ``matrices`` of a ``Rotation``, NaN for
        the observations not usable at every attitude."""
        epoch = self.epoch
        values = snr_db_or_nan(
            matrices,
            epoch.unit_los[None],
            epoch.boresight_rows[None],
            epoch.p0_dbw,
            epoch.noise_dbw,
            epoch.pattern,
            epoch.pattern_antenna,
            rotations=True,
        )
        values[:, np.isnan(values).any(axis=0)] = np.nan
        return values

    def symbolic(self) -> SymbolicModel:
        """:func:`~attopt.formulations.snr_model.snr_db` (or the truncated mean) of the epoch's
        lines of sight, receiving antennas' boresights, ``10 lg P0`` and noise power (and,
        when the antennas' patterns differ, the receiving antennas)."""
        epoch = self.epoch
        model = self._model or pattern_snr_model(epoch.pattern)
        parameters = (epoch.unit_los, epoch.boresight_rows, epoch.p0_dbw, epoch.noise_dbw)
        if epoch.pattern_antenna is not None:
            parameters += (epoch.pattern_antenna.astype(float),)
        return SymbolicModel(model, parameters)

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        matrices = attitude.as_matrix().reshape(-1, 3, 3)
        epoch = self.epoch
        if not jacobian:
            f = self._snr(matrices)
            if not self.truncated:
                return f, None
            x = (f - epoch.threshold_db) / self.sigma
            return f + self.sigma * inverse_mills_ratio(x), None
        values, jac = predict_snr(
            Rotation.from_quat(attitude.as_quat().reshape(-1, 4)),  # a stack, even of one
            epoch.unit_los[None],
            epoch.boresight_rows[None],
            epoch.p0_dbw[None],
            epoch.noise_dbw,
            epoch.pattern,
            mask="valid",
            model=self._model,
            antenna=None if epoch.pattern_antenna is None else epoch.pattern_antenna[None],
        )
        unusable = np.isnan(values).any(axis=0)  # for some attitude: NaN for all
        values[:, unusable] = np.nan
        jac[:, unusable] = np.nan
        return values, jac

    def batch_key(self) -> Hashable:
        """The pattern and the model (plain or truncated): epochs sharing them are predicted
        together (:meth:`predict_batch`)."""
        return (self.epoch.pattern, self._model, self.epoch.pattern_antenna is None)

    @classmethod
    def predict_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[tuple[Array, Array]]:
        """:meth:`predict` of each epoch at its attitude in one :func:`predict_snr` call, the
        epochs' observations one after another, each with its epoch's attitude."""
        rows = _StackedEpochs.of([m.epoch for m in measurements])
        rotations = Rotation.from_quat(attitudes.as_quat().reshape(-1, 4))  # as predict does
        values, jac = predict_snr(
            rotations[rows.epoch_of_row],
            rows.los,
            rows.boresight,
            rows.p0,
            rows.noise,
            measurements[0].epoch.pattern,
            mask="valid",
            model=measurements[0]._model,
            antenna=rows.antenna,
        )
        jac[np.isnan(values)] = np.nan
        return [
            (h.reshape(1, -1), j.reshape(1, -1, 3))
            for h, j in zip(rows.split(values), rows.split(jac), strict=True)
        ]

    def noise_covariance_at(self, attitude: Rotation) -> Array:
        if not self.truncated:
            return self.noise_covariance
        matrices = attitude.as_matrix().reshape(-1, 3, 3)[:1]
        return self._truncated_noise(self._snr(matrices)[0])

    def _truncated_noise(self, f: Array) -> Array:
        """``R`` of the truncated model at the untruncated SNRs ``f`` ``(m,)``."""
        factor = truncated_information_factor(f, self.sigma, self.epoch.threshold_db)
        return self.sigma**2 * np.where(np.isfinite(factor), factor, 1.0)

    @classmethod
    def noise_covariance_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[Array]:
        """:meth:`noise_covariance_at` of each epoch at its attitude; the truncated model's
        SNRs in one evaluation, the epochs' observations one after another."""
        if not measurements[0].truncated:
            return [m.noise_covariance for m in measurements]
        rows = _StackedEpochs.of([m.epoch for m in measurements])
        f = rows.untruncated_snr(attitudes, measurements[0].epoch.pattern)
        return [
            m._truncated_noise(part) for m, part in zip(measurements, rows.split(f), strict=True)
        ]

    def with_offsets(self, offsets: Array) -> SnrMeasurement:
        """The SNRs with each transmitter's power raised by ``offsets`` ``(m,)`` dB: the
        offsets enter as ``10 lg P0 + o`` (Liu et al. 2023 eq. 13)."""
        epoch = replace(self.epoch, p0_dbw=self.epoch.p0_dbw + np.asarray(offsets, dtype=float))
        return SnrMeasurement(epoch, truncated=self.truncated)

    def with_offset_spread(self, spread: float) -> SnrMeasurement:
        """The SNRs with each transmitter's power offset unknown, ``N(0, spread^2)`` dB and
        independent from row to row: each row's sigma widened to ``sqrt(sigma^2 +
        spread^2)`` (the SNR solvers' power prior, docs/adsb_sky.md)."""
        return SnrMeasurement(self.epoch.with_power_prior(0.0, spread), truncated=self.truncated)

    def offset_slope(self, attitude: Rotation) -> Array:
        """``dh / d (10 lg P0)`` ``(m,)``: 1 for the Gaussian model, the AD slope of the
        truncated mean (:func:`truncated_mean_slope`) at ``f(A)`` for the truncated one."""
        if not self.truncated:
            return np.ones(self.epoch.m)
        matrices = attitude.as_matrix().reshape(-1, 3, 3)[:1]
        return self._truncated_slope(self._snr(matrices)[0])

    @classmethod
    def offset_slope_batch(
        cls, measurements: Sequence[AttitudeMeasurement], attitudes: Rotation
    ) -> list[Array]:
        """:meth:`offset_slope` of each epoch at its attitude; the truncated model's SNRs in
        one evaluation, the epochs' observations one after another."""
        if not measurements[0].truncated:
            return [np.ones(m.epoch.m) for m in measurements]
        rows = _StackedEpochs.of([m.epoch for m in measurements])
        f = rows.untruncated_snr(attitudes, measurements[0].epoch.pattern)
        pairs = [(m.sigma, m.epoch.threshold_db) for m in measurements]
        noise, group = np.unique(np.array(pairs), axis=0, return_inverse=True)
        sizes = [m.epoch.m for m in measurements]
        return rows.split(_truncated_slope(f, noise, np.repeat(group.ravel(), sizes)))

    def _truncated_slope(self, f: Array) -> Array:
        noise = np.array([[self.sigma, self.epoch.threshold_db]])
        return _truncated_slope(f, noise, np.zeros(f.shape, dtype=np.intp))


@dataclass(frozen=True)
class _StackedEpochs:
    """Several epochs' observations one after another, one per row, as ``(rows, 1)`` inputs
    of the SNR model (with the epoch of each row, to give it its epoch's attitude)."""

    epoch_of_row: NDArray[np.intp]
    ends: NDArray[np.intp]
    los: Array
    boresight: Array
    p0: Array
    noise: Array
    antenna: NDArray[np.intp] | None

    @classmethod
    def of(cls, epochs: Sequence[SnrEpoch]) -> _StackedEpochs:
        counts = np.array([e.m for e in epochs], dtype=np.intp)
        antenna = None
        if epochs[0].pattern_antenna is not None:
            antenna = np.concatenate([e.pattern_antenna for e in epochs])[:, None]
        return cls(
            epoch_of_row=np.repeat(np.arange(len(epochs)), counts),
            ends=np.cumsum(counts)[:-1],
            los=np.concatenate([e.unit_los for e in epochs])[:, None],
            boresight=np.concatenate([e.boresight_rows for e in epochs])[:, None],
            p0=np.concatenate([e.p0_dbw for e in epochs])[:, None],
            noise=np.repeat([e.noise_dbw for e in epochs], counts)[:, None],
            antenna=antenna,
        )

    def untruncated_snr(self, attitudes: Rotation, pattern: Any) -> Array:
        """The untruncated model SNR ``f`` ``(rows,)`` of every row at its epoch's attitude
        (``attitudes``, one per epoch; NaN where unusable) with the epochs' ``pattern``
        (:attr:`SnrEpoch.pattern`, shared by the epochs of a batch)."""
        return snr_db_or_nan(
            attitudes.as_matrix().reshape(-1, 3, 3)[self.epoch_of_row],
            self.los,
            self.boresight,
            self.p0,
            self.noise,
            pattern,
            self.antenna,
            rotations=True,
        )[:, 0]

    def split(self, values: Array) -> list[Array]:
        """``values`` over the rows, epoch by epoch."""
        return np.split(values, self.ends)
