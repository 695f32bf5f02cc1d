"""Observation counts padded to bucket sizes, so compiled problems are reused.

CasADi functions and IPOPT problems are built for a fixed number of
observations.  An epoch with ``m`` observations is padded to the smallest
bucket in :data:`BUCKETS` that holds it (beyond 256 the buckets keep
doubling), so a pass with ``m`` varying from epoch to epoch reuses at most a
handful of compiled problems per process.  Padding rows have weight 0 and
measured SNR 0, and a harmless geometry: the line of sight lies along the
padding boresight at the reference attitude (``cos alpha = 1``, the gain is
finite and smooth there for every pattern), so they add exactly nothing to the
loss, its gradient or its Hessian.  When the antennas' patterns differ, the
padded epoch also carries each row's receiving antenna (padding rows: that of
the padding boresight), the extra input of the compiled functions
(:mod:`attopt.formulations.snr_model`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from attopt.formulations.snr_problem import SnrEpoch

Array = NDArray[np.float64]

BUCKETS = (8, 16, 32, 64, 128, 256)
"""Problem size classes (numbers of observation rows)."""


def bucket_size(m: int) -> int:
    """The smallest bucket holding ``m`` observations (powers of two beyond 256)."""
    for size in BUCKETS:
        if m <= size:
            return size
    return 1 << (m - 1).bit_length()


@dataclass(frozen=True)
class PaddedEpoch:
    """An epoch's observations padded to :attr:`size` rows.

    Attributes:
        m: number of real observations (rows ``0..m-1``).
        los: ``(size, 3)`` unit lines of sight, orbit frame.
        boresight: ``(size, 3)`` unit boresight of the receiving antenna, body frame.
        p0: ``(size,)`` isotropic power (dBW).
        noise: noise power (dBW).
        weights: ``(size,)`` ``1 / sigma_k^2``, 0 for padding rows.
        snr: ``(size,)`` measured SNR (dB), 0 for padding rows.
        antenna: ``(size,)`` receiving antenna of each row (as floats) when the
            antennas' patterns differ, else ``None``.
    """

    m: int
    los: Array
    boresight: Array
    p0: Array
    noise: float
    weights: Array
    snr: Array
    antenna: Array | None = None

    @property
    def size(self) -> int:
        return int(self.weights.shape[0])

    @property
    def model_inputs(self) -> tuple[Array | float, ...]:
        """The per-epoch inputs of the compiled SNR functions, in the order of
        :func:`attopt.formulations.snr_model.symbolic_inputs`."""
        inputs = (self.los, self.boresight, self.p0, self.noise)
        return inputs if self.antenna is None else (*inputs, self.antenna)


def pad_epoch(problem: SnrEpoch, attitude_ref: Array, size: int | None = None) -> PaddedEpoch:
    """Pad ``problem`` to ``size`` rows (default :func:`bucket_size`).

    ``attitude_ref`` (``3 x 3``) places the padding lines of sight on the
    padding boresight, ``A_ref^T b``: that of the antenna of the first
    observation (validated finite), or nadir for an empty epoch.
    """
    m = problem.m
    size = bucket_size(m) if size is None else size
    if size < m:
        raise ValueError(f"cannot pad {m} observations to {size} rows")
    pad_antenna = int(problem.antenna[0]) if m else 0
    pad_boresight = problem.boresight_rows[0] if m else np.array([0.0, 0.0, 1.0])
    los = np.empty((size, 3))
    boresight = np.empty((size, 3))
    los[:m] = problem.unit_los
    los[m:] = pad_boresight @ attitude_ref
    boresight[:m] = problem.boresight_rows
    boresight[m:] = pad_boresight
    p0 = np.zeros(size)
    p0[:m] = problem.p0_dbw
    weights = np.zeros(size)
    weights[:m] = problem.weights
    snr = np.zeros(size)
    snr[:m] = problem.snr_db
    antenna = None
    if problem.pattern_antenna is not None:
        antenna = np.full(size, float(pad_antenna))
        antenna[:m] = problem.pattern_antenna
    return PaddedEpoch(m, los, boresight, p0, problem.noise_dbw, weights, snr, antenna)
