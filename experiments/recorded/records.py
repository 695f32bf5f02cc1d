"""Tables and ``pass.toml`` entries of arrays and library objects: what an export writes.

The inverse of :mod:`~attopt.experiments.recorded.build`: each function lays
out what an estimator consumed in the columns of
:data:`~attopt.experiments.recorded.tables.TABLES`, values untouched, so the
pass built from the tables is the pass the arrays made.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from attopt.experiments.recorded.metadata import PriorEntry
from attopt.formulations.passes import GyroRecord, Prior
from attopt.formulations.snapshot import VECTOR_COLUMNS


def _xyz_columns(prefix: str, values: ArrayLike, unit: str = "") -> dict[str, np.ndarray]:
    values = np.asarray(values, dtype=float)
    suffix = f"_{unit}" if unit else ""
    return {f"{prefix}_{a}{suffix}": values[:, i] for i, a in enumerate("xyz")}


def vector_table(
    t: ArrayLike,
    sensors: Sequence[str],
    body: ArrayLike,
    reference: ArrayLike,
    sigma: ArrayLike,
) -> pd.DataFrame:
    """The ``vectors`` table of ``k`` sensors at ``N`` epochs ``t``: ``body`` ``(N, k, 3)``
    (NaN rows: not measured, left out as :meth:`Pass.from_vectors
    <attopt.formulations.passes.Pass.from_vectors>` leaves them out), ``reference``
    ``(N, k, 3)`` or ``(k, 3)``, ``sigma`` broadcastable to ``(N, k)`` (rad); rows epoch
    by epoch, sensors in order.

    Example::

        >>> import numpy as np
        >>> from attopt.experiments.recorded.records import vector_table
        >>> body = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[np.nan] * 3, [0.0, 1.0, 0.0]]])
        >>> table = vector_table([0.0, 1.0], ["sun", "mag"], body, np.eye(3)[:2], [1e-3, 1e-2])
        >>> table[["t_s", "sensor", "sigma_rad"]].to_numpy().tolist()
        [[0.0, 'sun', 0.001], [0.0, 'mag', 0.01], [1.0, 'mag', 0.01]]
    """
    body = np.asarray(body, dtype=float)
    shape = body.shape[:2]
    reference = np.broadcast_to(np.asarray(reference, dtype=float), body.shape)
    present = np.isfinite(body).all(axis=2) & np.isfinite(reference).all(axis=2)
    values = np.concatenate([body, reference], axis=2)[present]
    return pd.DataFrame(
        {
            "t_s": np.broadcast_to(np.asarray(t, dtype=float)[:, None], shape)[present],
            "sensor": np.broadcast_to(np.asarray(sensors, dtype=object), shape)[present],
            **{name: values[:, i] for i, name in enumerate(VECTOR_COLUMNS)},
            "sigma_rad": np.broadcast_to(np.asarray(sigma, dtype=float), shape)[present],
        }
    )


def snr_table(
    *,
    t: ArrayLike,
    antenna: ArrayLike,
    transmitter: ArrayLike,
    transmitter_km: ArrayLike,
    los: ArrayLike,
    p0_dbw: ArrayLike,
    snr_db: ArrayLike,
    sigma_db: ArrayLike,
) -> pd.DataFrame:
    """The ``snr`` table of ``M`` received messages, one row each in the given order:
    times, antenna indices and transmitter ids ``(M,)``, transmitter positions
    ``(M, 3)`` (km, ``position_frame``), unit lines of sight ``(M, 3)``
    (``attitude_frame``), isotropic powers and measured SNRs ``(M,)`` and the SNR sigma,
    broadcastable to ``(M,)`` (dB).

    Example::

        >>> from attopt.experiments.recorded.records import snr_table
        >>> table = snr_table(
        ...     t=[0.0], antenna=[1], transmitter=[7], transmitter_km=[[7000.0, 0.0, 0.0]],
        ...     los=[[0.0, 0.0, 1.0]], p0_dbw=[-130.0], snr_db=[12.5], sigma_db=1.0,
        ... )
        >>> table[["antenna", "transmitter", "los_z", "sigma_db"]].to_numpy().tolist()
        [[1.0, 7.0, 1.0, 1.0]]
    """
    snr = np.asarray(snr_db, dtype=float)
    return pd.DataFrame(
        {
            "t_s": np.asarray(t, dtype=float),
            "antenna": np.asarray(antenna, dtype=np.int64),
            "transmitter": np.asarray(transmitter, dtype=np.int64),
            **_xyz_columns("transmitter", transmitter_km, "km"),
            **_xyz_columns("los", los),
            "p0_dbw": np.asarray(p0_dbw, dtype=float),
            "snr_db": snr,
            "sigma_db": np.broadcast_to(np.asarray(sigma_db, dtype=float), snr.shape),
        }
    )


def epochs_table(t: ArrayLike) -> pd.DataFrame:
    """The ``epochs`` table: every epoch time, also those without an observation."""
    return pd.DataFrame({"t_s": np.asarray(t, dtype=float)})


def gyro_table(record: GyroRecord) -> pd.DataFrame:
    """The ``gyro`` table of a record: one row per sample time, the last row's rates NaN
    (it closes the record)."""
    rates = np.vstack([record.rates, np.full((1, 3), np.nan)])
    return pd.DataFrame({"t_s": record.t, **_xyz_columns("rate", rates, "rad_s")})


def position_table(t: ArrayLike, position_km: ArrayLike, velocity_km_s: ArrayLike) -> pd.DataFrame:
    """The ``position`` table: the satellite's position and velocity at times ``t``."""
    return pd.DataFrame(
        {
            "t_s": np.asarray(t, dtype=float),
            **_xyz_columns("position", position_km, "km"),
            **_xyz_columns("velocity", velocity_km_s, "km_s"),
        }
    )


def truth_table(t: ArrayLike, attitude: Rotation) -> pd.DataFrame:
    """The ``truth`` table: scipy's scalar-last quaternions of ``attitude`` at ``t`` as
    scipy holds them (not made canonical), so they load as the same rotations."""
    q = attitude.as_quat()
    return pd.DataFrame(
        {"t_s": np.asarray(t, dtype=float), **{f"q_{c}": q[:, i] for i, c in enumerate("xyzw")}}
    )


def prior_entry(prior: Prior, frame: str) -> PriorEntry:
    """The ``[prior]`` of ``prior``, an attitude relative to ``frame``."""
    return PriorEntry(
        frame=frame,
        quaternion=tuple(prior.attitude.as_quat().tolist()),
        covariance=tuple(tuple(row) for row in prior.covariance.tolist()),
        bias_rad_s=None if prior.bias is None else tuple(np.asarray(prior.bias).tolist()),
        rate_rad_s=None if prior.rate is None else tuple(np.asarray(prior.rate).tolist()),
    )
