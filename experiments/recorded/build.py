"""From a recorded pass's checked tables and metadata to the library objects estimators consume.

Every geometric quantity is taken as stored (lines of sight, isotropic powers,
covariances), or computed by the same function the simulations use (the orbit
frame, :func:`~attopt.formulations.conventions.orbit_frame_attitude`; the
measurements re-expressed for the gyro's inertial frame,
:func:`~attopt.experiments.simulation.referenced`), so a pass built from the
simulated arrays and the same pass loaded from disk are the same to the last
bit.  Quaternions of unit norm are used exactly as stored
(:func:`stored_rotation`).  Each function raises
:class:`~attopt.experiments.recorded.errors.PassFormatError` naming the table,
the column and the row of what is wrong.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.recorded.errors import PassFormatError
from attopt.experiments.recorded.metadata import (
    FILE,
    INERTIAL,
    ORBIT,
    DoaEntry,
    GyroEntry,
    PassMetadata,
    SnrEntry,
)
from attopt.experiments.recorded.tables import OBSERVATIONS, TABLES, fail
from attopt.formulations.attitude_measurement import AttitudeMeasurement, VectorMeasurement
from attopt.formulations.conventions import orbit_frame_attitude
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import shared_pattern
from attopt.formulations.passes import GyroRecord, Prior
from attopt.formulations.snapshot import VECTOR_COLUMNS, Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch

Array = NDArray[np.float64]
Tables = Mapping[str, pd.DataFrame]
Rows = pd.DataFrame | Mapping[str, np.ndarray]
"""Rows of a table: a frame, or its columns by name as arrays (what :func:`snapshots`
hands the per-epoch builders: slicing arrays is far cheaper than slicing a frame)."""

UNIT_TOLERANCE = 1e-12
"""Quaternions whose norm is 1 to this are used as stored; others are normalised."""


def columns(frame: Rows, names: list[str] | tuple[str, ...]) -> Array:
    """The columns ``names`` of ``frame`` as one C-ordered float array ``(rows, len(names))``."""
    return np.column_stack([np.asarray(frame[name], dtype=float) for name in names])


def xyz(frame: Rows, prefix: str, unit: str = "") -> Array:
    """The ``(rows, 3)`` columns ``{prefix}_{x,y,z}[_{unit}]``."""
    suffix = f"_{unit}" if unit else ""
    return columns(frame, [f"{prefix}_{a}{suffix}" for a in "xyz"])


def stored_rotation(quaternion: Array, table: str, column: str = "q_x..q_w") -> Rotation:
    """Rotations of scalar-last quaternions ``(n, 4)`` or ``(4,)``.

    Those of unit norm to :data:`UNIT_TOLERANCE` become scipy's rotation of exactly
    those four numbers (``Rotation(q, normalize=False)``), so a rotation saved with
    ``as_quat()`` loads as the same rotation, bit for bit; others are normalised.

    Raises:
        PassFormatError: a quaternion that is zero or not finite.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt.experiments.recorded.build import stored_rotation
        >>> r = Rotation.from_rotvec([0.1, 0.2, 0.3]) * Rotation.from_rotvec([0.3, 0.2, 0.1])
        >>> bool(np.array_equal(stored_rotation(r.as_quat(), "truth").as_quat(), r.as_quat()))
        True
    """
    q = np.asarray(quaternion, dtype=float)
    norm = np.linalg.norm(q, axis=-1)
    fail(table, column, np.atleast_1d(~(np.isfinite(norm) & (norm > 0))), "zero or not finite")
    if np.all(np.abs(norm - 1.0) <= UNIT_TOLERANCE):
        return Rotation(q, normalize=False)
    return Rotation.from_quat(q)


def epoch_times(tables: Tables) -> Array:
    """The epochs: the ``epochs`` table's times, else every observation time, sorted.

    Raises:
        PassFormatError: no epoch at all, or an ``epochs`` table that does not increase.
    """
    if "epochs" in tables:
        t = tables["epochs"]["t_s"].to_numpy(dtype=float)
        fail("epochs", "t_s", np.concatenate([[False], np.diff(t) <= 0]), "must increase")
    else:
        present = [
            tables[name]["t_s"].to_numpy(dtype=float) for name in OBSERVATIONS if name in tables
        ]
        t = np.unique(np.concatenate([np.zeros(0), *present]))
    if not t.size:
        raise PassFormatError.at("epochs", problem="the pass has no epoch (no observation)")
    return t


def epoch_rows(name: str, frame: pd.DataFrame, t: Array) -> list[NDArray[np.intp]]:
    """Per epoch, the rows of observation table ``name`` at its time, in file order.

    Raises:
        PassFormatError: a row whose time is not an epoch.
    """
    times = frame["t_s"].to_numpy(dtype=float)
    index = np.minimum(np.searchsorted(t, times), t.size - 1)
    fail(name, "t_s", t[index] != times, "not a time of the epochs table")
    order = np.argsort(index, kind="stable")
    bounds = np.searchsorted(index[order], np.arange(t.size + 1))
    return [order[a:b] for a, b in itertools.pairwise(bounds)]


def vector_measurement(rows: Rows) -> VectorMeasurement:
    """One epoch's rows of the ``vectors`` table as one measurement (Cilden Guler et al.
    2017 eqs. 2-4)."""
    values = columns(rows, VECTOR_COLUMNS)
    sigma = np.asarray(rows["sigma_rad"], dtype=float)
    return VectorMeasurement(values[:, :3], values[:, 3:], sigma)


def snr_measurements(rows: Rows, snr: SnrEntry) -> list[SnrMeasurement]:
    """One epoch's rows of the ``snr`` table as one :class:`SnrMeasurement`: every antenna's
    boresight, the antenna index as stored and the antennas' gain pattern, the one pattern
    when they share it, else one per antenna
    (:func:`~attopt.formulations.gain_patterns.shared_pattern`)."""
    epoch = SnrEpoch(
        snr_db=np.asarray(rows["snr_db"], dtype=float),
        los_orbit=xyz(rows, "los"),
        antenna=np.asarray(rows["antenna"], dtype=np.intp),
        boresights_body=np.array([a.boresight_body for a in snr.antennas], dtype=float),
        p0_dbw=np.asarray(rows["p0_dbw"], dtype=float),
        noise_dbw=snr.noise_dbw,
        pattern=shared_pattern([antenna.pattern.pattern() for antenna in snr.antennas]),
        sigma_db=np.asarray(rows["sigma_db"], dtype=float),
        threshold_db=snr.threshold_db,
        transmitter=np.asarray(rows["transmitter"], dtype=np.intp),
    )
    return [SnrMeasurement(epoch, truncated=snr.truncated)]


def doa_measurement(rows: Rows, doa: DoaEntry) -> DoaMeasurement:
    """One epoch's rows of the ``doa`` table as one measurement (Yang et al. 2014 eqs. 12-18)."""
    names = [f"cov_{a}_{b}_rad2" for a in ("theta", "phi") for b in ("theta", "phi")]
    return DoaMeasurement(
        columns(rows, ["theta_rad", "phi_rad"]),
        columns(rows, names).reshape(-1, 2, 2),
        xyz(rows, "los", "km"),
        lever_arm=np.array(doa.lever_arm_km),
        mounting=stored_rotation(
            np.array(doa.mounting_quaternion), FILE, "doa.mounting_quaternion"
        ),
        far_field=doa.far_field,
        axis_threshold=doa.axis_threshold_rad,
    )


def _check_observations(tables: Tables, metadata: PassMetadata) -> None:
    if "vectors" in tables:
        sigma = tables["vectors"]["sigma_rad"].to_numpy(dtype=float)
        fail("vectors", "sigma_rad", ~(sigma > 0), "must be positive")
    if "snr" in tables:
        if metadata.snr is None:
            raise PassFormatError.at(FILE, "snr", None, "missing: the pass has an snr table")
        snr = tables["snr"]
        antenna = snr["antenna"].to_numpy()
        n = len(metadata.snr.antennas)
        fail("snr", "antenna", (antenna < 0) | (antenna >= n), f"not one of the {n} antennas")
        fail("snr", "sigma_db", ~(snr["sigma_db"].to_numpy(float) > 0), "must be positive")


def snapshots(tables: Tables, metadata: PassMetadata, t: Array) -> list[Snapshot | None]:
    """One snapshot per epoch of the observation tables' rows (vectors, then SNRs, then
    DOAs), ``None`` where an epoch has none.

    Raises:
        PassFormatError: a bad observation, naming its table, column and row (a model's
            own objection names the epoch's first row).
    """
    _check_observations(tables, metadata)
    doa = metadata.doa or DoaEntry()
    builders = {
        "vectors": lambda rows: [vector_measurement(rows)],
        "snr": lambda rows: snr_measurements(rows, metadata.snr),
        "doa": lambda rows: [doa_measurement(rows, doa)],
    }
    parts: list[list[AttitudeMeasurement]] = [[] for _ in t]
    for name, build in builders.items():
        if name not in tables:
            continue
        frame = tables[name]
        arrays = {column: frame[column].to_numpy() for column in frame.columns}
        for k, rows in enumerate(epoch_rows(name, frame, t)):
            if not rows.size:
                continue
            try:
                parts[k] += build({column: values[rows] for column, values in arrays.items()})
            except InvalidObservationError as error:
                raise PassFormatError.at(name, None, int(rows[0]), str(error)) from None
    return [
        Snapshot(tuple(m), float(time)) if m else None for m, time in zip(parts, t, strict=True)
    ]


def gyro_record(table: pd.DataFrame | None, entry: GyroEntry | None) -> GyroRecord | None:
    """The ``gyro`` table with its ``[gyro]`` model (both or neither).

    Raises:
        PassFormatError: one without the other, times that do not increase, a sample
            spacing other than the model's, or too few samples.
    """
    if table is None and entry is None:
        return None
    if entry is None:
        raise PassFormatError.at(FILE, "gyro", None, "missing: the pass has a gyro table")
    if table is None:
        raise PassFormatError.at("gyro", problem=f"missing: {FILE} has a [gyro] table")
    t = table["t_s"].to_numpy(dtype=float)
    fail("gyro", "t_s", np.concatenate([[False], np.diff(t) <= 0]), "must increase")
    try:
        return GyroRecord(t, xyz(table, "rate", "rad_s")[:-1], entry.model())
    except InvalidObservationError as error:
        raise PassFormatError.at("gyro", "t_s", None, str(error)) from None


def orbit_frames(table: pd.DataFrame | None, metadata: PassMetadata, t: Array) -> Rotation:
    """``A_oi`` at the epochs: the orbit frame of the ``position`` table's ECI position and
    velocity at each epoch (:func:`~attopt.formulations.conventions.orbit_frame_attitude`).

    Raises:
        PassFormatError: no position table, positions not in ECI, or an epoch without a
            row or without a finite velocity.
    """
    if table is None:
        raise PassFormatError.at("position", problem="missing: the orbit frame needs it")
    if metadata.position_frame != INERTIAL:
        raise PassFormatError.at(
            FILE,
            "position_frame",
            None,
            f"the orbit frame needs ECI positions, not {metadata.position_frame!r}",
        )
    times = table["t_s"].to_numpy(dtype=float)
    row = np.searchsorted(times, t)
    at_epoch = (row < times.size) & (times[np.minimum(row, times.size - 1)] == t)
    if not at_epoch.all():
        first = float(t[np.flatnonzero(~at_epoch)[0]])
        raise PassFormatError.at("position", "t_s", None, f"no row at the epoch t_s = {first:g}")
    rows = table.iloc[row]
    velocity = xyz(rows, "velocity", "km_s")
    fail("position", "velocity_x_km_s", ~np.isfinite(velocity).all(axis=1), "needs a velocity")
    return orbit_frame_attitude(xyz(rows, "position", "km"), velocity)


def truth(table: pd.DataFrame | None, t: Array) -> Rotation | None:
    """The ``truth`` table's attitudes, one per epoch in epoch order.

    Raises:
        PassFormatError: a truth time that is not an epoch, or an epoch without one.
    """
    if table is None:
        return None
    times = table["t_s"].to_numpy(dtype=float)
    order = np.argsort(times, kind="stable")
    if times.size != t.size or not np.array_equal(times[order], t):
        index = np.minimum(np.searchsorted(t, times), t.size - 1)
        fail("truth", "t_s", (t[index] != times) | _repeated(times), "not one row per epoch")
        raise PassFormatError.at("truth", "t_s", None, f"{times.size} rows for {t.size} epochs")
    return stored_rotation(columns(table, [f"q_{c}" for c in "xyzw"])[order], "truth")


def _repeated(values: Array) -> NDArray[np.bool_]:
    _, first = np.unique(values, return_index=True)
    repeated = np.ones(values.size, dtype=bool)
    repeated[first] = False
    return repeated


def priors(metadata: PassMetadata) -> tuple[Prior | None, Prior | None]:
    """The priors of the two passes: that of the attitude relative to
    :attr:`~PassMetadata.attitude_frame` (``pass_``'s) and, with a gyro, that relative to
    ECI (the gyro-aided pass's; the same one with an ECI attitude), ``None`` where
    ``pass.toml`` has none.

    Raises:
        PassFormatError: a prior that neither pass uses (relative to another frame), or
            one the library rejects.
    """
    frames = {metadata.attitude_frame}
    if metadata.gyro is not None:
        frames.add(INERTIAL)
    for k, entry in enumerate(metadata.prior):
        if entry.frame not in frames:
            used = " or ".join(repr(frame) for frame in sorted(frames))
            raise PassFormatError.at(
                FILE,
                f"{_prior_key(metadata, k)}.frame",
                None,
                f"the pass estimators estimate the attitude relative to {used}, "
                f"not {entry.frame!r}",
            )
    inertial = _prior(metadata, INERTIAL) if metadata.gyro is not None else None
    return _prior(metadata, metadata.attitude_frame), inertial


def _prior_key(metadata: PassMetadata, k: int) -> str:
    return "prior" if len(metadata.prior) == 1 else f"prior.{k}"


def _prior(metadata: PassMetadata, frame: str) -> Prior | None:
    entry = metadata.prior_in(frame)
    if entry is None:
        return None
    key = _prior_key(metadata, metadata.prior.index(entry))
    optional = {"bias": entry.bias_rad_s, "rate": entry.rate_rad_s}
    try:
        return Prior(
            stored_rotation(np.array(entry.quaternion), FILE, f"{key}.quaternion"),
            np.array(entry.covariance, dtype=float),
            **{k: np.array(v, dtype=float) for k, v in optional.items() if v is not None},
        )
    except (InvalidObservationError, ValueError) as error:
        raise PassFormatError.at(FILE, key, None, str(error)) from None


def needs_orbit_frames(metadata: PassMetadata) -> bool:
    """Whether the epochs' orbit frames are needed: an orbit-frame attitude with a gyro
    (measurements re-expressed for the inertial attitude) or rigid-body dynamics."""
    moving = metadata.gyro is not None or metadata.dynamics is not None
    return metadata.attitude_frame == ORBIT and moving


def require_tables(tables: Tables) -> None:
    """Raise for a table name the format does not have."""
    unknown = sorted(set(tables) - set(TABLES))
    if unknown:
        raise PassFormatError.at(", ".join(unknown), problem=f"unknown (known: {sorted(TABLES)})")
