"""A recorded pass: its metadata and tables, the library :class:`Pass` they make, the truth.

:class:`RecordedPass` is built from ``pass.toml``'s
:class:`~attopt.experiments.recorded.metadata.PassMetadata` and the tables of
:data:`~attopt.experiments.recorded.tables.TABLES`, checked once on
construction; :func:`load_pass` reads one from a directory, :func:`save_pass`
writes one (``docs/pass-format.md``).  A simulated pass exported with the
arrays its experiment consumed and the same pass loaded from disk build the
same objects, so estimators give bit-identical estimates on both.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from attopt.experiments.recorded.build import (
    epoch_times,
    gyro_record,
    needs_orbit_frames,
    orbit_frames,
    priors,
    require_tables,
    snapshots,
    truth,
)
from attopt.experiments.recorded.errors import PassFormatError
from attopt.experiments.recorded.metadata import FILE, INERTIAL, ORBIT, PassMetadata
from attopt.experiments.recorded.tables import FORMATS, TABLES, checked, read_table, write_table
from attopt.experiments.simulation import referenced
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import Pass, RigidBody, epoch_snapshots


@dataclass(frozen=True, eq=False)
class RecordedPass:
    """A pass as recorded: ``metadata`` (``pass.toml``) and ``tables`` (name -> frame).

    Built on construction (every table checked, :class:`PassFormatError` naming
    table, column and row for what is wrong):

    Attributes:
        pass_: the :class:`~attopt.formulations.passes.Pass` of the measurements
            relative to ``metadata.attitude_frame``: what the snapshot estimators and
            those on rigid-body dynamics solve.  It carries the prior relative to that
            frame, the gyro when it refers to that frame (an ECI attitude) and the
            rigid-body dynamics (orbit frame).
        gyro_pass: the pass the gyro-aided estimators solve (``None`` without a gyro):
            with an orbit-frame attitude, the measurements re-expressed for the attitude
            relative to ECI with the epochs' orbit frames (``A_bi = A_bo A_oi``,
            :func:`~attopt.experiments.simulation.referenced`), the gyro and the prior
            relative to ECI; else the measurements, gyro and prior of ``pass_``.
        frames: ``A_oi`` at the epochs when the orbit frame is needed, else ``None``.
        truth: the true attitude (``attitude_frame`` -> body) at the epochs, or ``None``.

    Example::

        >>> import pandas as pd
        >>> from attopt.experiments.recorded import PassMetadata, RecordedPass
        >>> vectors = pd.DataFrame({
        ...     "t_s": [0.0, 0.0], "sensor": ["sun", "magnetometer"],
        ...     "body_x": [1.0, 0.0], "body_y": [0.0, 1.0], "body_z": [0.0, 0.0],
        ...     "reference_x": [1.0, 0.0], "reference_y": [0.0, 1.0], "reference_z": [0.0, 0.0],
        ...     "sigma_rad": [1e-3, 1e-2],
        ... })
        >>> RecordedPass(PassMetadata(attitude_frame="eci"), {"vectors": vectors})
        RecordedPass(attitude eci, Pass(1 epochs, t 0-0 s, 1 with measurements), tables vectors)
    """

    metadata: PassMetadata
    tables: Mapping[str, pd.DataFrame]
    pass_: Pass = field(init=False, repr=False)
    gyro_pass: Pass | None = field(init=False, repr=False)
    frames: Rotation | None = field(init=False, repr=False)
    truth: Rotation | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        require_tables(self.tables)
        tables = {name: checked(name, frame) for name, frame in self.tables.items()}
        metadata = self.metadata
        t = epoch_times(tables)
        measured = snapshots(tables, metadata, t)
        gyro = gyro_record(tables.get("gyro"), metadata.gyro)
        frames = (
            orbit_frames(tables.get("position"), metadata, t)
            if needs_orbit_frames(metadata)
            else None
        )
        own, inertial_prior = priors(metadata)
        inertial = metadata.attitude_frame == INERTIAL
        try:
            pass_ = Pass(t, measured, gyro if inertial else None, own, _dynamics(metadata, frames))
            gyro_pass = None
            if gyro is not None:
                moved = pass_.snapshots if inertial else referenced(measured, frames)
                gyro_pass = Pass(t, epoch_snapshots(moved, t), gyro, inertial_prior)
        except InvalidObservationError as error:
            raise PassFormatError.at("gyro", "t_s", None, str(error)) from None
        for name, value in (
            ("tables", tables),
            ("pass_", pass_),
            ("gyro_pass", gyro_pass),
            ("frames", frames),
            ("truth", truth(tables.get("truth"), t)),
        ):
            object.__setattr__(self, name, value)

    @property
    def t(self) -> np.ndarray:
        """The epoch times (s from the pass start)."""
        return self.pass_.t

    def __repr__(self) -> str:
        names = ", ".join(name for name in TABLES if name in self.tables)
        return (
            f"RecordedPass(attitude {self.metadata.attitude_frame}, {self.pass_!r}, tables {names})"
        )


def _dynamics(metadata: PassMetadata, frames: Rotation | None) -> RigidBody | None:
    entry = metadata.dynamics
    if entry is None:
        return None
    if metadata.attitude_frame != ORBIT:
        raise PassFormatError.at(
            FILE, "dynamics", None, "rigid-body dynamics need attitude_frame = 'orbit'"
        )
    return RigidBody(np.array(entry.inertia_kg_m2), frames, np.array(entry.wheel_momentum_n_m_s))


def load_pass(path: str | Path) -> RecordedPass:
    """The recorded pass in directory ``path`` (``docs/pass-format.md``), checked.

    Raises:
        PassFormatError: no such directory, no ``pass.toml``, or anything in it or in
            its tables that does not follow the format (naming table, column and row).

    Example::

        >>> import tempfile
        >>> import pandas as pd
        >>> import attopt
        >>> from attopt.experiments.recorded import PassMetadata, RecordedPass
        >>> truth = pd.DataFrame({"t_s": [0.0], "q_x": 0.0, "q_y": 0.0, "q_z": 0.0, "q_w": 1.0})
        >>> vectors = pd.DataFrame({
        ...     "t_s": [0.0, 0.0], "sensor": ["sun", "magnetometer"],
        ...     "body_x": [1.0, 0.0], "body_y": [0.0, 1.0], "body_z": [0.0, 0.0],
        ...     "reference_x": [1.0, 0.0], "reference_y": [0.0, 1.0], "reference_z": [0.0, 0.0],
        ...     "sigma_rad": [1e-3, 1e-2],
        ... })
        >>> recorded = RecordedPass(
        ...     PassMetadata(attitude_frame="eci"), {"vectors": vectors, "truth": truth}
        ... )
        >>> directory = attopt.save_pass(recorded, tempfile.mkdtemp())
        >>> loaded = attopt.load_pass(directory)
        >>> attopt.estimator("quest").solve_pass(loaded.pass_).valid.tolist()
        [True]
    """
    directory = Path(path)
    if not directory.is_dir():
        raise PassFormatError(f"{directory}: no such pass directory")
    metadata = PassMetadata.read(directory)
    tables = {name: read_table(directory, name) for name in TABLES}
    return RecordedPass(
        metadata, {name: frame for name, frame in tables.items() if frame is not None}
    )


def save_pass(recorded: RecordedPass, path: str | Path, fmt: str = "parquet") -> Path:
    """Write ``recorded`` to directory ``path`` (created if needed; a pass already there is
    replaced): ``pass.toml`` and one ``fmt`` file (``parquet`` or, for small data,
    ``csv``) per table.  Returns the directory.

    Example::

        >>> import tempfile
        >>> import pandas as pd
        >>> import attopt
        >>> from attopt.experiments.recorded import PassMetadata, RecordedPass
        >>> epochs = pd.DataFrame({"t_s": [0.0, 1.0]})
        >>> recorded = RecordedPass(PassMetadata(attitude_frame="orbit"), {"epochs": epochs})
        >>> directory = attopt.save_pass(recorded, tempfile.mkdtemp(), fmt="csv")
        >>> sorted(p.name for p in directory.iterdir())
        ['epochs.csv', 'pass.toml']
    """
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, not {fmt!r}")
    directory = Path(path)
    directory.mkdir(parents=True, exist_ok=True)
    for name in TABLES:
        for old in FORMATS:
            (directory / f"{name}.{old}").unlink(missing_ok=True)
    (directory / FILE).write_text(recorded.metadata.to_text())
    for name, frame in recorded.tables.items():
        write_table(directory, name, frame, fmt)
    return directory
