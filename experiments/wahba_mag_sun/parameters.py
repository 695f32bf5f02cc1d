"""The tables of ``wahba-mag-sun``'s parameters that describe its world: the true
attitude (``[attitude]``), the magnetometer (``[magnetometer]``) and the Sun sensor
(``[sun_sensor]``), and the default orbit (:data:`TIMED`).

The defaults are Cilden Guler et al. 2017 sec. 3's set-up as
:mod:`attopt.experiments.wahba_mag_sun.scenario` realises it: the paper's
direction-cosine noise of 0.008 (magnetometer) and 0.002 (Sun sensor), an attitude
profile imitating its Fig. 2, and TIMED's orbit from a recent TLE.  The whole schema,
with the window, the orbit and the estimators, is
:class:`~attopt.experiments.wahba_mag_sun.experiment.WahbaMagSunParameters`.
"""

from __future__ import annotations

from pydantic import Field

from attopt.experiments.config import Parameters
from attopt.experiments.config.components import TleOrbit

TIMED = TleOrbit(
    line1="1 26998U 01055B   26130.94162250  .00000829  00000+0  79016-4 0  9991",
    line2="2 26998  74.0671 310.0081 0001049 187.4151 172.7018 14.95201872325257",
)
"""TIMED (NORAD 26998), epoch 26130.94162250 = 2026-05-10 22:35:56.184 UTC."""


class AttitudeProfile(Parameters):
    """``[attitude]``: the true orbit -> body attitude, 3-2-1 Euler angles (Liu et al. 2023
    eq. 8) with ``t`` in seconds from ``start_utc``::

        pitch(t) = pitch_amplitude cos(2 pi (t - pitch_peak) / pitch_period)
        roll(t)  = roll_amplitude sin(2 pi t / roll_period)
        yaw(t)   = yaw_amplitude sin(2 pi t / yaw_period)

    The defaults imitate the pitch of Cilden Guler et al. 2017 Fig. 2 (close to +/-90 deg
    near 1000 s and 3800 s) with a small roll and yaw.
    """

    pitch_amplitude_deg: float = Field(87.0, ge=-180.0, le=180.0, description="Pitch amplitude.")
    pitch_peak_s: float = Field(
        1000.0, allow_inf_nan=False, description="Time of the pitch maximum."
    )
    pitch_period_s: float = Field(
        5600.0, gt=0.0, allow_inf_nan=False, description="Period of the pitch."
    )
    roll_amplitude_deg: float = Field(3.0, ge=-180.0, le=180.0, description="Roll amplitude.")
    roll_period_s: float = Field(
        1500.0, gt=0.0, allow_inf_nan=False, description="Period of the roll."
    )
    yaw_amplitude_deg: float = Field(4.0, ge=-180.0, le=180.0, description="Yaw amplitude.")
    yaw_period_s: float = Field(
        2300.0, gt=0.0, allow_inf_nan=False, description="Period of the yaw."
    )


SIGMA_DESCRIPTION = (
    "Direction noise per axis across the measured unit vector (direction cosines, "
    "radians for small errors)."
)
"""What ``sigma_rad`` means: ``b = normalise(A r + sigma eps)``, ``eps ~ N(0, I3)``
(Cilden Guler et al. 2017 eqs. 2 and 4), so each direction-cosine component of the
noise has standard deviation ``sigma`` and, to first order, so does the error angle about
each axis perpendicular to the vector (the variance ``sigma^2 (I - b b^T)`` of Shuster's
measurement model, the Wahba weight ``1 / sigma^2``)."""


class Magnetometer(Parameters):
    """``[magnetometer]``: the measured geomagnetic-field direction (IGRF at the epoch)."""

    sigma_rad: float = Field(0.008, gt=0.0, allow_inf_nan=False, description=SIGMA_DESCRIPTION)


class SunSensor(Parameters):
    """``[sun_sensor]``: the measured Sun direction, none in the Earth's cylindrical
    shadow."""

    sigma_rad: float = Field(0.002, gt=0.0, allow_inf_nan=False, description=SIGMA_DESCRIPTION)
