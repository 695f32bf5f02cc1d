"""M2M4 SNR estimator on constant-modulus (PSK) samples in AWGN (Pimienta-Penalver and
Crassidis sec. III, eqs. 8-11).

Samples ``y_k = x_k + n_k`` (eq. 8), ``|x_k|^2 = S``, ``n_k`` circular complex
Gaussian with ``E|n_k|^2 = N``; ``SNR = S / N`` (eq. 9).  With the sample
moments ``M2 = mean |y|^2`` and ``M4 = mean |y|^4`` (eq. 10), ``E[M2] = S + N``
and ``E[M4] = S^2 + 4 S N + 2 N^2``, so (eq. 11)::

    S = sqrt(2 M2^2 - M4),   N = M2 - S.

The estimator is consistent but biased upward at low SNR and small sample
counts (``docs/geo.md``).  The discriminant ``2 M2^2 - M4`` is negative when
the sample kurtosis exceeds that of a constant-modulus signal plus noise
(frequent below 0 dB with tens of samples); such an estimate is flagged
invalid with the reason, never returned as NaN dB.  ``N = 0`` (noise-free
samples) is flagged too: the SNR is unbounded.

M2M4 needs a constant-modulus signal: it does not apply to the on-off keyed
(pulse-position modulated) ADS-B pulses of Liu et al. 2023, whose envelope has the
same kurtosis as complex noise, so the moments carry no SNR information.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import InvalidObservationError

Array = NDArray[np.float64]

TABLE3_SNR_DB = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0)
"""True SNRs of Pimienta-Penalver and Crassidis Table 3."""
TABLE3_PAPER_DB = (0.02, 2.025, 4.034, 5.98, 7.99, 10.04)
"""Mean estimated SNRs printed in Pimienta-Penalver and Crassidis Table 3 (mean error 0.0148 dB)."""
NEGATIVE_DISCRIMINANT = "negative discriminant 2 M2^2 - M4 <= 0: no signal power in the moments"
ZERO_NOISE = "noise power estimate M2 - S <= 0: SNR unbounded (noise-free samples)"


@dataclass(frozen=True)
class M2M4Estimate:
    """M2M4 estimates for a batch of sample records (leading axes of the samples).

    ``snr_db`` is a masked array, masked where ``valid`` is False; ``reason``
    is ``""`` for valid estimates and names the failure otherwise.
    """

    signal_power: Array
    noise_power: Array
    valid: NDArray[np.bool_]
    reason: NDArray[np.str_]

    @property
    def snr_db(self) -> np.ma.MaskedArray:
        """``10 lg(S / N)`` (dB), masked where invalid."""
        ratio = self.signal_power / np.where(self.valid, self.noise_power, 1.0)
        return np.ma.masked_array(10.0 * np.log10(np.where(self.valid, ratio, 1.0)), ~self.valid)


def estimate_snr(samples: ArrayLike) -> M2M4Estimate:
    """M2M4 estimate (eqs. 10-11) from complex samples, records along the last axis."""
    y = np.asarray(samples)
    if y.ndim < 1 or y.shape[-1] < 2:
        raise InvalidObservationError(f"need at least 2 samples per record, got shape {y.shape}")
    if not np.all(np.isfinite(y)):
        raise InvalidObservationError("samples contain NaN/inf")
    power = np.abs(y) ** 2
    m2 = power.mean(axis=-1)
    m4 = (power**2).mean(axis=-1)
    discriminant = 2.0 * m2**2 - m4
    signal = np.sqrt(np.maximum(discriminant, 0.0))
    noise = m2 - signal
    has_signal = discriminant > 0
    has_noise = noise > 0
    reason = np.where(has_signal, np.where(has_noise, "", ZERO_NOISE), NEGATIVE_DISCRIMINANT)
    return M2M4Estimate(signal, noise, has_signal & has_noise, reason)


def simulate_psk(
    snr_db: ArrayLike,
    n_samples: int,
    rng: np.random.Generator,
    order: int = 4,
    signal_power: float = 1.0,
) -> NDArray[np.complex128]:
    """Received M-PSK samples ``y = x + n`` (eq. 8), shape ``shape(snr_db) + (n_samples,)``.

    Symbols ``sqrt(S) exp(2 pi j m / order)`` with ``m`` uniform; noise
    circular complex Gaussian with ``E|n|^2 = S / 10^(snr_db / 10)``.
    """
    snr = np.asarray(snr_db, dtype=float)
    if n_samples < 1 or order < 2 or not np.all(np.isfinite(snr)):
        raise InvalidObservationError("need n_samples >= 1, order >= 2 and finite SNRs")
    shape = (*snr.shape, n_samples)
    symbols = np.exp(2j * np.pi * rng.integers(order, size=shape) / order)
    noise_std = np.sqrt(signal_power / 10.0 ** (snr[..., None] / 10.0) / 2.0)
    noise = noise_std * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    return np.sqrt(signal_power) * symbols + noise


@dataclass(frozen=True)
class SnrTable:
    """Monte Carlo statistics of M2M4 at each true SNR (dB)."""

    true_db: Array
    mean_db: Array
    """Mean of the valid estimates in dB (NaN only if all are invalid: ``invalid_fraction`` 1)."""
    std_db: Array
    """Standard deviation of the valid estimates in dB."""
    invalid_fraction: Array


def snr_table(
    rng: np.random.Generator,
    n_samples: int,
    n_trials: int,
    true_db: ArrayLike = TABLE3_SNR_DB,
    order: int = 4,
) -> SnrTable:
    """Table 3 of Pimienta-Penalver and Crassidis: M2M4 on ``n_trials`` records of
    ``n_samples`` at each SNR."""
    truth = np.asarray(true_db, dtype=float)
    estimate = estimate_snr(
        simulate_psk(np.repeat(truth[:, None], n_trials, axis=1), n_samples, rng, order)
    )
    snr = estimate.snr_db
    return SnrTable(
        true_db=truth,
        mean_db=snr.mean(axis=1).filled(np.nan),
        std_db=snr.std(axis=1).filled(np.nan),
        invalid_fraction=1.0 - estimate.valid.mean(axis=1),
    )
