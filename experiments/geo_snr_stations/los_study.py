"""Line-of-sight error against station geometry (Pimienta-Penalver and Crassidis Figs. 2-3).

The satellite sits on the GEO belt (:func:`attopt.formulations.geo_geometry.belt_position`)
with its beam at nadir and the attitude known; a station of the world's ``[[stations]]``
hears it when the noise-free SNR of the world's link is at least the receivers'
``detection_threshold_db``.  Noisy SNR sets (the receivers' ``snr_sigma_db``) of the
hearing stations (ECEF) are solved for the belt longitude by
:func:`attopt.solvers.geo.los.locate_on_geo_belt`, all stations together and each alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from attopt.experiments.environment.traffic import MEAN_RADIUS_KM as MEAN_EARTH_RADIUS_KM
from attopt.experiments.geo_snr_stations.parameters import GeoWorld
from attopt.experiments.geo_snr_stations.scenario import stations_ecef_km
from attopt.formulations.geo_geometry import belt_position, line_of_sight_errors
from attopt.formulations.geo_link import attitude_pointing, main_lobe_snr_db
from attopt.solvers.geo.los import locate_on_geo_belt


@dataclass(frozen=True)
class LosStudyRow:
    """RMS line-of-sight error at one station (Pimienta-Penalver and Crassidis Figs. 2-3)."""

    station: str
    ground_distance_km: float
    """Great-circle distance (mean Earth radius) from the sub-satellite point."""
    snr_db: float
    joint_rms_deg: float
    """Every station that hears the satellite fitted together."""
    single_rms_deg: float
    """This station's SNR alone, longitude window +-``window_deg`` about the truth."""


def los_geometry_study(
    satellite_longitude_deg: float,
    rng: np.random.Generator,
    n_trials: int = 50,
    window_deg: float = 0.5,
    world: GeoWorld | None = None,
) -> list[LosStudyRow]:
    """LOS error vs station geometry: satellite on the belt at the given longitude, beam at
    nadir, ``n_trials`` noisy SNR sets of ``world``'s stations, link and receivers (default:
    the paper's; module docstring)."""
    world = GeoWorld() if world is None else world
    link, sigma_db = world.link(), world.receiver.snr_sigma_db
    stations, up = stations_ecef_km(world.stations)
    satellite = belt_position(np.radians(satellite_longitude_deg))
    attitude = attitude_pointing(-satellite)
    truth = main_lobe_snr_db(attitude.as_matrix(), satellite, stations, link)
    heard = np.flatnonzero(truth >= world.receiver.detection_threshold_db)
    joint = np.empty((n_trials, heard.size))
    single = np.empty((n_trials, heard.size))
    window = (satellite_longitude_deg - window_deg, satellite_longitude_deg + window_deg)
    for trial in range(n_trials):
        y = truth[heard] + sigma_db * rng.standard_normal(heard.size)
        fit = locate_on_geo_belt(y, stations[heard], up[heard], attitude, sigma_db, link)
        joint[trial] = line_of_sight_errors(fit.satellite_km, satellite, stations[heard])
        for j, i in enumerate(heard):
            alone = locate_on_geo_belt(
                y[[j]], stations[[i]], up[[i]], attitude, sigma_db, link, window_deg=window
            )
            single[trial, j] = line_of_sight_errors(alone.satellite_km, satellite, stations[[i]])[0]
    sub = satellite / np.linalg.norm(satellite)
    central = np.arccos(np.clip(up[heard] @ sub, -1.0, 1.0))
    joint_rms = np.degrees(np.sqrt(np.mean(joint**2, axis=0)))
    single_rms = np.degrees(np.sqrt(np.mean(single**2, axis=0)))
    return [
        LosStudyRow(
            world.stations[i].name,
            float(MEAN_EARTH_RADIUS_KM * central[j]),
            float(truth[i]),
            float(joint_rms[j]),
            float(single_rms[j]),
        )
        for j, i in enumerate(heard)
    ]
