"""The tables of a recorded pass: their columns, units and frames, read, checked and written.

One file per table in the pass directory, ``NAME.parquet`` (float64 is stored
exactly) or ``NAME.csv`` (floats written in their shortest round-trip form and
read back by pandas' parser, which rounds correctly, so also exactly; for small data).
:data:`TABLES` is the schema that ``docs/pass-format.md`` documents; a table is
checked on load against it (:func:`checked`): unknown and missing columns,
values of the wrong type, and NaN or infinite values where a column does not
allow them are :class:`~attopt.experiments.recorded.errors.PassFormatError`
naming the table, the column and the first bad row (0-based, the file's data
rows in order).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from attopt.experiments.recorded.errors import PassFormatError
from attopt.formulations.snapshot import VECTOR_COLUMNS

Kind = Literal["float", "int", "str"]
FORMATS = ("parquet", "csv")


@dataclass(frozen=True)
class Column:
    """One column: its name, value type, unit and meaning; ``finite``: NaN and inf are errors."""

    name: str
    kind: Kind
    unit: str
    description: str
    finite: bool = True


@dataclass(frozen=True)
class Table:
    """One table of the format: name, what one row is, and its columns."""

    name: str
    row: str
    columns: tuple[Column, ...]

    @property
    def names(self) -> list[str]:
        return [column.name for column in self.columns]


TIME = Column("t_s", "float", "s", "time from the pass start (`start_utc`)")


def _xyz(prefix: str, unit: str, description: str, finite: bool = True) -> tuple[Column, ...]:
    return tuple(
        Column(f"{prefix}_{axis}{unit and '_' + unit}", "float", unit, description, finite)
        for axis in "xyz"
    )


def _vector_columns() -> tuple[Column, ...]:
    meaning = {
        "body": "measured unit vector, body frame",
        "reference": "its reference direction, `attitude_frame`",
    }
    return tuple(Column(name, "float", "1", meaning[name.split("_")[0]]) for name in VECTOR_COLUMNS)


TABLES: dict[str, Table] = {
    table.name: table
    for table in (
        Table("epochs", "one epoch (optional: else the observations' times)", (TIME,)),
        Table(
            "gyro",
            "one sample: the mean rate over [t_s, next t_s); the last row closes the record",
            (TIME, *_xyz("rate", "rad_s", "measured body rate, body axes", finite=False)),
        ),
        Table(
            "vectors",
            "one measured unit vector",
            (
                TIME,
                Column("sensor", "str", "", "the sensor's name (e.g. sun, magnetometer)"),
                *_vector_columns(),
                Column("sigma_rad", "float", "rad", "direction noise standard deviation"),
            ),
        ),
        Table(
            "snr",
            "one received message",
            (
                TIME,
                Column("antenna", "int", "", "receiving antenna: index into `[[snr.antennas]]`"),
                Column("transmitter", "int", "", "transmitter identifier"),
                *_xyz("transmitter", "km", "transmitter position, `position_frame`", False),
                *_xyz("los", "", "line of sight satellite -> transmitter, `attitude_frame`"),
                Column("p0_dbw", "float", "dBW", "isotropic received power 10 lg P0"),
                Column("snr_db", "float", "dB", "measured SNR"),
                Column("sigma_db", "float", "dB", "SNR noise standard deviation"),
            ),
        ),
        Table(
            "doa",
            "one ground station's direction of arrival",
            (
                TIME,
                Column("station", "int", "", "station identifier"),
                Column("theta_rad", "float", "rad", "polar angle from the array axis"),
                Column("phi_rad", "float", "rad", "azimuth from the array x axis"),
                *(
                    Column(f"cov_{a}_{b}_rad2", "float", "rad^2", f"covariance of {a} and {b}")
                    for a in ("theta", "phi")
                    for b in ("theta", "phi")
                ),
                *_xyz("los", "km", "centre of mass -> station, `attitude_frame`"),
                *_xyz("station", "km", "station position, `position_frame`", False),
            ),
        ),
        Table(
            "position",
            "the satellite's state at one time",
            (
                TIME,
                *_xyz("position", "km", "position, `position_frame`"),
                *_xyz("velocity", "km_s", "velocity, `position_frame`", False),
            ),
        ),
        Table(
            "truth",
            "the true attitude at one epoch",
            (
                TIME,
                *(
                    Column(
                        f"q_{c}", "float", "1", "quaternion, scalar last: `attitude_frame` -> body"
                    )
                    for c in "xyzw"
                ),
            ),
        ),
    )
}
"""Every table of the format, by name."""
OBSERVATIONS = ("vectors", "snr", "doa")
"""The tables whose rows are measurements."""


def fail(table: str, column: str, bad: np.ndarray, problem: str) -> None:
    """Raise :class:`PassFormatError` at the first row of ``bad`` (a mask), if any."""
    rows = np.flatnonzero(bad)
    if rows.size:
        raise PassFormatError.at(table, column, int(rows[0]), problem)


def _numbers(table: str, column: Column, values: pd.Series) -> np.ndarray:
    numbers = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
    if not pd.api.types.is_numeric_dtype(values):
        fail(table, column.name, np.isnan(numbers) & values.notna().to_numpy(), "is not a number")
    if values.dtype == bool or not pd.api.types.is_numeric_dtype(values):
        raise PassFormatError.at(
            table, column.name, None, f"must be {column.kind}, not {values.dtype}"
        )
    if column.finite:
        fail(table, column.name, ~np.isfinite(numbers), f"{column.kind} value is NaN or infinite")
    if column.kind == "int":
        fail(table, column.name, numbers != np.round(numbers), "is not an integer")
        return numbers.astype(np.int64)
    return numbers


def checked(name: str, frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` as table ``name`` of :data:`TABLES`, each column of its type (module
    docstring).

    Raises:
        PassFormatError: an unknown or missing column, a value of the wrong type, or NaN
            where the column needs a finite value.
    """
    table = TABLES[name]
    unknown = [str(c) for c in frame.columns if c not in table.names]
    if unknown:
        raise PassFormatError.at(name, ", ".join(unknown), None, f"unknown (known: {table.names})")
    missing = [c for c in table.names if c not in frame.columns]
    if missing:
        raise PassFormatError.at(name, ", ".join(missing), None, "missing")
    columns = {}
    for column in table.columns:
        values = frame[column.name].reset_index(drop=True)
        if column.kind == "str":
            text = values.map(lambda v: isinstance(v, str) and v != "").to_numpy(dtype=bool)
            fail(name, column.name, ~text, "must be a non-empty string")
            columns[column.name] = values.astype(object)
        else:
            columns[column.name] = _numbers(name, column, values)
    return pd.DataFrame(columns)


def table_file(directory: Path, name: str) -> Path | None:
    """The file of table ``name`` in ``directory`` (``None`` if there is none).

    Raises:
        PassFormatError: both a parquet and a CSV file.
    """
    found = [Path(directory) / f"{name}.{fmt}" for fmt in FORMATS]
    found = [path for path in found if path.is_file()]
    if len(found) > 1:
        raise PassFormatError.at(name, problem=f"both {found[0].name} and {found[1].name}")
    return found[0] if found else None


def read_table(directory: Path, name: str) -> pd.DataFrame | None:
    """Table ``name`` of a pass directory, checked (:func:`checked`); ``None`` if absent."""
    path = table_file(directory, name)
    if path is None:
        return None
    try:
        if path.suffix == ".parquet":
            frame = pd.read_parquet(path)
        else:
            strings = {c.name: str for c in TABLES[name].columns if c.kind == "str"}
            frame = pd.read_csv(path, dtype=strings)
    except (OSError, ValueError) as error:
        raise PassFormatError.at(name, problem=f"cannot read {path.name}: {error}") from None
    return checked(name, frame)


def write_table(directory: Path, name: str, frame: pd.DataFrame, fmt: str = "parquet") -> Path:
    """Write table ``name`` to ``directory`` as ``fmt`` (``parquet`` or ``csv``)."""
    path = Path(directory) / f"{name}.{fmt}"
    frame = frame[TABLES[name].names]
    if fmt == "parquet":
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)
    return path
