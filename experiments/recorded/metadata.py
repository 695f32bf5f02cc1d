"""``pass.toml``: what a recorded pass says besides its tables (``docs/pass-format.md``).

A pydantic schema (the same library as the experiments' configuration): the
frames, the gyro's model, the SNR antennas with their gain patterns and the
link's noise power and threshold, the DOA array and its mounting, the priors
(at most one per frame: the estimators on rigid-body dynamics start from the
attitude frame's, the gyro-aided ones from the ECI one) and the rigid-body
dynamics.  Each part turns into the library object the
estimators consume (:class:`~attopt.formulations.gyro.GyroModel`, the
patterns of :mod:`attopt.formulations.gain_patterns`, ...), and back
(:func:`pattern_entry`, :func:`gyro_entry`).  Every error of a document is
reported at once, by key.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from tomli_w import dumps

from attopt.experiments.config.components import repeated
from attopt.experiments.recorded.errors import PassFormatError
from attopt.formulations.doa_measurement import AXIS_THRESHOLD
from attopt.formulations.gain_patterns import (
    CosinePowerPattern,
    GainPattern,
    ParabolicPattern,
    TabulatedPattern,
)
from attopt.formulations.gyro import GyroModel
from attopt.formulations.snr_problem import RECEPTION_THRESHOLD_DB

FILE = "pass.toml"
FORMAT_VERSION = 1
INERTIAL = "eci"
"""The inertial frame (astropy's GCRS, ``docs/conventions.md``): the gyro's reference."""
ORBIT = "orbit"
"""The orbit frame of the satellite's ECI position and velocity (``docs/conventions.md``)."""
Frame = Literal["eci", "orbit"]
PositionFrame = Literal["eci", "ecef"]
Vector3 = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]


class Entry(BaseModel):
    """A table of ``pass.toml``: unknown keys are errors, values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class GyroEntry(Entry):
    """``[gyro]``: the model the ``gyro`` table's samples follow (:class:`GyroModel`)."""

    name: str = Field(description="label of the gyro")
    rate_hz: float = Field(gt=0, description="sampling rate; the samples are 1 / rate_hz apart")
    angle_random_walk_rad_sqrt_s: float = Field(ge=0, description="sigma_v, rad/s^(1/2)")
    rate_random_walk_rad_s_sqrt_s: float = Field(ge=0, description="sigma_u, rad/s^(3/2)")
    initial_bias_sigma_rad_s: float = Field(ge=0, description="turn-on bias sigma per axis")

    def model(self) -> GyroModel:
        """The :class:`GyroModel`."""
        return GyroModel(
            self.name,
            sigma_v=self.angle_random_walk_rad_sqrt_s,
            sigma_u=self.rate_random_walk_rad_s_sqrt_s,
            initial_bias_sigma=self.initial_bias_sigma_rad_s,
            rate_hz=self.rate_hz,
        )


def gyro_entry(model: GyroModel) -> GyroEntry:
    """The ``[gyro]`` table of ``model``.

    Example::

        >>> from attopt import MEMS_GYRO
        >>> from attopt.experiments.recorded.metadata import gyro_entry
        >>> gyro_entry(MEMS_GYRO).model() == MEMS_GYRO
        True
    """
    return GyroEntry(
        name=model.name,
        rate_hz=model.rate_hz,
        angle_random_walk_rad_sqrt_s=model.sigma_v,
        rate_random_walk_rad_s_sqrt_s=model.sigma_u,
        initial_bias_sigma_rad_s=model.initial_bias_sigma,
    )


class CosinePowerEntry(Entry):
    """``type = "cosine_power"``: :class:`CosinePowerPattern` (Liu et al. 2023 eq. 63)."""

    type: Literal["cosine_power"] = "cosine_power"
    peak_gain: float = Field(description="linear boresight gain")
    exponent: float = Field(description="power of cos(alpha)")
    min_gain_dbi: float = Field(description="main-lobe edge")

    def pattern(self) -> GainPattern:
        return CosinePowerPattern(self.peak_gain, self.exponent, self.min_gain_dbi)


class ParabolicEntry(Entry):
    """``type = "parabolic"``: :class:`ParabolicPattern` (Pimienta-Penalver and Crassidis
    eq. 5)."""

    type: Literal["parabolic"] = "parabolic"
    peak_gain_dbi: float
    theta_3db_rad: float = Field(description="half-power beamwidth")
    min_gain_dbi: float = Field(description="main-lobe edge")
    size_factor_db: float = Field(12.0, description="C of the parabola")

    def pattern(self) -> GainPattern:
        return ParabolicPattern(
            self.peak_gain_dbi, self.theta_3db_rad, self.min_gain_dbi, self.size_factor_db
        )


class TabulatedEntry(Entry):
    """``type = "tabulated"``: :class:`TabulatedPattern`, gain against the off-boresight angle."""

    type: Literal["tabulated"] = "tabulated"
    angles_rad: tuple[float, ...]
    gains_dbi: tuple[float, ...]

    def pattern(self) -> GainPattern:
        return TabulatedPattern(self.angles_rad, self.gains_dbi)


PatternEntry = Annotated[
    CosinePowerEntry | ParabolicEntry | TabulatedEntry, Field(discriminator="type")
]


def pattern_entry(pattern: GainPattern) -> CosinePowerEntry | ParabolicEntry | TabulatedEntry:
    """The ``pattern`` table of a library gain pattern.

    Example::

        >>> from attopt.experiments.recorded.metadata import pattern_entry
        >>> from attopt.formulations.gain_patterns import LIU2023_HELIX
        >>> entry = pattern_entry(LIU2023_HELIX)
        >>> entry.type, entry.pattern() == LIU2023_HELIX
        ('cosine_power', True)
    """
    if isinstance(pattern, CosinePowerPattern):
        return CosinePowerEntry(
            peak_gain=pattern.peak_gain,
            exponent=pattern.exponent,
            min_gain_dbi=pattern.min_gain_dbi,
        )
    if isinstance(pattern, ParabolicPattern):
        return ParabolicEntry(
            peak_gain_dbi=pattern.peak_gain_dbi,
            theta_3db_rad=pattern.theta_3db_rad,
            min_gain_dbi=pattern.min_gain_dbi,
            size_factor_db=pattern.size_factor_db,
        )
    if isinstance(pattern, TabulatedPattern):
        return TabulatedEntry(angles_rad=pattern.angles_rad, gains_dbi=pattern.gains_dbi)
    raise TypeError(f"no pass-format entry for the gain pattern {type(pattern).__name__}")


class AntennaEntry(Entry):
    """``[[snr.antennas]]``: one receiving antenna; the ``snr`` table's ``antenna`` is its
    position in this list (0-based)."""

    name: str = ""
    boresight_body: Vector3 = Field(description="boresight in the body frame (normalised)")
    pattern: PatternEntry


class SnrEntry(Entry):
    """``[snr]``: what the SNR measurements (:class:`~attopt.formulations.snr_problem.SnrEpoch`)
    need besides the ``snr`` table."""

    noise_dbw: float = Field(description="noise power 10 lg(k_B T B), Liu et al. 2023 eq. 2")
    threshold_db: float = Field(RECEPTION_THRESHOLD_DB, description="reception threshold")
    truncated: bool = Field(False, description="the threshold-truncated measurement model")
    antennas: tuple[AntennaEntry, ...] = Field(min_length=1)


class ArrayEntry(Entry):
    """``[doa.array]``: the uniform circular array (Yang et al. 2014 eqs. 19-21)."""

    n_elements: int = Field(gt=0)
    radius_m: float = Field(gt=0)
    wavelength_m: float = Field(gt=0)


class DoaEntry(Entry):
    """``[doa]``: the mounting of the DOA array
    (:class:`~attopt.formulations.doa_measurement.DoaMeasurement`)."""

    lever_arm_km: Vector3 = Field((0.0, 0.0, 0.0), description="centre of mass -> array, body")
    mounting_quaternion: Quaternion = Field(
        (0.0, 0.0, 0.0, 1.0), description="body -> array rotation, scalar last"
    )
    far_field: bool = False
    axis_threshold_rad: float = Field(AXIS_THRESHOLD, gt=0)
    array: ArrayEntry | None = None


class PriorEntry(Entry):
    """One ``[prior]``: an initial estimate (:class:`~attopt.formulations.passes.Prior`) of
    the attitude relative to ``frame`` at the first epoch (with a gyro, at the first gyro
    sample).  A pass has at most one per frame (:attr:`PassMetadata.prior`)."""

    frame: Frame = Field(description="frame the prior attitude is relative to")
    quaternion: Quaternion = Field(description="reference -> body, scalar last")
    covariance: tuple[tuple[float, ...], ...] = Field(description="3x3 or 6x6, rad^2 (rad/s)^2")
    bias_rad_s: Vector3 | None = None
    rate_rad_s: Vector3 | None = None


class DynamicsEntry(Entry):
    """``[dynamics]``: the rigid body (:class:`~attopt.formulations.passes.RigidBody`); its
    orbit frames are those of the ``position`` table."""

    inertia_kg_m2: tuple[Vector3, Vector3, Vector3]
    wheel_momentum_n_m_s: Vector3 = (0.0, 0.0, 0.0)


class PassMetadata(Entry):
    """The whole of ``pass.toml`` (``docs/pass-format.md``).

    Example::

        >>> from attopt.experiments.recorded.metadata import PassMetadata
        >>> metadata = PassMetadata(attitude_frame="orbit", description="my pass")
        >>> PassMetadata.from_text(metadata.to_text()) == metadata
        True
    """

    format_version: Literal[1] = FORMAT_VERSION
    description: str = ""
    start_utc: str = Field("", description="ISO UTC time of t_s = 0, if known")
    attitude_frame: Frame = Field(description="frame the attitude (and truth) is relative to")
    position_frame: PositionFrame = Field(INERTIAL, description="frame of every position")
    gyro: GyroEntry | None = None
    snr: SnrEntry | None = None
    doa: DoaEntry | None = None
    prior: tuple[PriorEntry, ...] = Field(
        (), description="the priors, at most one per frame: one [prior] or [[prior]] tables"
    )
    dynamics: DynamicsEntry | None = None

    @field_validator("start_utc")
    @classmethod
    def _iso(cls, value: str) -> str:
        if value:
            np.datetime64(value)  # ValueError for a malformed time
        return value

    @field_validator("prior", mode="before")
    @classmethod
    def _one_or_many(cls, value: Any) -> Any:
        """One table (``[prior]``, a mapping or an entry) is a tuple of one; ``None``, none."""
        if value is None:
            return ()
        return (value,) if isinstance(value, Mapping | PriorEntry) else value

    @field_validator("prior")
    @classmethod
    def _one_per_frame(cls, value: tuple[PriorEntry, ...]) -> tuple[PriorEntry, ...]:
        twice = repeated([entry.frame for entry in value])
        if twice:
            frames = ", ".join(repr(frame) for frame in twice)
            raise ValueError(f"at most one prior per frame, not several relative to {frames}")
        return value

    def prior_in(self, frame: str) -> PriorEntry | None:
        """The prior of the attitude relative to ``frame``, ``None`` if there is none.

        Example::

            >>> from attopt.experiments.recorded.metadata import PassMetadata, PriorEntry
            >>> eci = PriorEntry(frame="eci", quaternion=(0.0, 0.0, 0.0, 1.0),
            ...                  covariance=((1e-4, 0.0, 0.0), (0.0, 1e-4, 0.0), (0.0, 0.0, 1e-4)))
            >>> metadata = PassMetadata(attitude_frame="orbit", prior=eci)
            >>> metadata.prior_in("eci") == eci, metadata.prior_in("orbit")
            (True, None)
        """
        return next((entry for entry in self.prior if entry.frame == frame), None)

    def to_text(self) -> str:
        """The TOML text of the metadata (exact floats): one prior as a ``[prior]`` table,
        several as ``[[prior]]`` tables, none left out."""
        document = self.model_dump(mode="python", exclude_none=True)
        priors = document["prior"]
        if not priors:
            del document["prior"]
        elif len(priors) == 1:
            document["prior"] = priors[0]
        return dumps(document)

    @classmethod
    def from_text(cls, text: str) -> PassMetadata:
        """Parse and validate ``pass.toml`` text.

        Raises:
            PassFormatError: malformed TOML, or every key that is missing, unknown
                or bad, each with its value.
        """
        try:
            document = tomllib.loads(text)
        except tomllib.TOMLDecodeError as error:
            raise PassFormatError.at(FILE, problem=f"not TOML: {error}") from None
        try:
            return cls.model_validate(document)
        except ValidationError as error:
            one_prior = isinstance(document.get("prior"), Mapping)
            raise PassFormatError(f"{FILE}: {_problems(error, one_prior)}") from None

    @classmethod
    def read(cls, directory: Path) -> PassMetadata:
        """The ``pass.toml`` of a pass directory."""
        path = Path(directory) / FILE
        if not path.is_file():
            raise PassFormatError.at(FILE, problem=f"missing in {directory}")
        return cls.from_text(path.read_text())


def _problems(error: ValidationError, one_prior: bool = False) -> str:
    """Every error of a validation, ``key.path: message (got value)``, joined by ``; ``
    (``one_prior``: the document's ``[prior]`` is one table, its keys ``prior.KEY``)."""
    parts = []
    for item in error.errors():
        loc = item["loc"]
        if one_prior and loc[:2] == ("prior", 0):
            loc = ("prior", *loc[2:])
        key = ".".join(str(part) for part in loc) or "(document)"
        got = "" if item["type"] == "missing" else f" (got {item['input']!r})"
        parts.append(f"key {key}: {item['msg']}{got}")
    return "; ".join(parts)
