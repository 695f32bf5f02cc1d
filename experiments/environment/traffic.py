"""Global airborne traffic on great-circle routes between real airports (Liu et al. 2023 sec. 5.1).

Liu et al. 2023 sec. 5.1 feeds its simulation with one hour of real global flight data
(VariFlight).  No package ships such a snapshot, so this module synthesises a
population with the same geography from the airports of :mod:`airportsdata`.

The numbers below are the defaults of :class:`TrafficModel`, which the
experiment's ``[traffic]`` table sets.

Airports.  ``airportsdata`` gives coordinates but no airport type or size.  We
keep the airports with an IATA code and an alphabetic four-letter ICAO code
(about 7,600; this drops private strips known only by local identifiers) and
give each a size proxy ``w = 1``, times ``international_weight`` (5) if its name
contains "International" and times ``metropolitan_weight`` (20) if it serves one
of the IATA multi-airport metropolitan areas (``airportsdata.load_iata_macs``:
about 90 airports of London, New York, Tokyo, Beijing, Sao Paulo, ...).

Routes.  Origin and destination are drawn independently with probability
proportional to ``w`` and the pair is kept with probability
``f(d) = exp(-(d - d_min) / d_scale)`` if the great-circle distance is
``d_min <= d <= d_max`` (rejected otherwise; 500 km, 2,000 km and 10,000 km): a
gravity model favouring short- and medium-haul routes (median route about
2,100 km).  Dense airport regions gain from the distance preference, so with
10,000 aircraft about 33 % fly over North America, 26 % over Europe and 15 %
over East Asia, and almost none over the South Pacific.

Motion.  Routes are great circles on the sphere of geodetic normals
``n = (cos lat cos lon, cos lat sin lon, sin lat)`` (WGS84 latitude and
longitude treated as spherical coordinates).  Each aircraft cruises at a
geodetic height uniform in a band (9-12 km) with a ground speed uniform in a
band (220-260 m/s), and at ``t = 0`` has flown a uniform random fraction of its
route.  It turns
through the angle ``v t / (R1 + h)`` per time ``t`` (``R1`` the mean Earth
radius), so its WGS84 (ECEF) speed differs from ``v`` by less than 0.6 %.  On
arrival it flies straight back along the same route (no turnaround time; climb
and descent are not modelled), so every aircraft stays airborne and the
population and its geography are stationary.  Positions at any time follow in
closed form, so they are computed on demand for the epochs and aircraft needed.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import airportsdata
import astropy.units as u
import erfa
import numpy as np
from astropy.coordinates import EarthLocation
from numpy.typing import ArrayLike, NDArray

WGS84_A_KM = erfa.eform(erfa.WGS84)[0] / 1000.0
"""WGS84 equatorial radius (km)."""
WGS84_F = erfa.eform(erfa.WGS84)[1]
"""WGS84 flattening."""
MEAN_RADIUS_KM = WGS84_A_KM * (1.0 - WGS84_F / 3.0)
"""Mean Earth radius ``R1 = (2a + b) / 3`` (km)."""

_ICAO_CODE = re.compile(r"[A-Z]{4}")
_ROUTE_BATCH = 50_000


@dataclass(frozen=True)
class TrafficModel:
    """The numbers of the traffic model (module docstring)."""

    international_weight: float = 5.0
    """Factor of the size proxy of an airport named "International"."""
    metropolitan_weight: float = 20.0
    """Factor of the size proxy of an airport of an IATA metropolitan area."""
    min_route_km: float = 500.0
    """Shortest great-circle route ``d_min``."""
    max_route_km: float = 10_000.0
    """Longest great-circle route ``d_max``."""
    route_scale_km: float = 2000.0
    """Scale ``d_scale`` of the exponential distance preference ``f(d)``."""
    height_range_km: tuple[float, float] = (9.0, 12.0)
    """Band of the geodetic cruise heights (uniform)."""
    speed_range_m_s: tuple[float, float] = (220.0, 260.0)
    """Band of the ground speeds (uniform)."""


@dataclass(frozen=True)
class Airports:
    """Airports usable as route ends, ``M`` of them."""

    iata: NDArray[np.str_]
    normal: NDArray[np.float64]
    """Unit geodetic normals (ECEF), ``(M, 3)``."""
    weight: NDArray[np.float64]
    """Size proxy ``w`` of the module docstring, ``(M,)``."""


@dataclass(frozen=True)
class Traffic:
    """``n`` aircraft on great-circle routes; aircraft ``j`` is row ``j`` of each array."""

    origin: NDArray[np.str_]
    """IATA code of the airport the aircraft left last."""
    destination: NDArray[np.str_]
    origin_normal: NDArray[np.float64]
    """Unit geodetic normal of the origin, ``(n, 3)``."""
    route_tangent: NDArray[np.float64]
    """Unit tangent at the origin towards the destination, ``(n, 3)``."""
    route_angle_rad: NDArray[np.float64]
    """Central angle from origin to destination."""
    start_angle_rad: NDArray[np.float64]
    """Central angle flown from the origin at ``t = 0``."""
    height_km: NDArray[np.float64]
    """Geodetic (WGS84) cruise height."""
    speed_mps: NDArray[np.float64]
    """Ground speed."""

    @property
    def size(self) -> int:
        """Number of aircraft."""
        return self.origin.size

    @property
    def route_normal(self) -> NDArray[np.float64]:
        """Unit normal of each route's great-circle plane, ``(n, 3)``."""
        return np.cross(self.origin_normal, self.route_tangent)

    @property
    def angular_rate_rad_s(self) -> NDArray[np.float64]:
        """Central angle flown per second, ``v / (R1 + h)``."""
        return self.speed_mps / (1000.0 * (MEAN_RADIUS_KM + self.height_km))


@functools.lru_cache(maxsize=4)
def load_airports(international_weight: float = 5.0, metropolitan_weight: float = 20.0) -> Airports:
    """Airports with IATA and four-letter ICAO codes and their size proxy (module docstring)."""
    records = [
        record
        for record in airportsdata.load("IATA").values()
        if _ICAO_CODE.fullmatch(record["icao"])
    ]
    metropolitan = {
        code for area in airportsdata.load_iata_macs().values() for code in area["airports"]
    }
    international = np.array(["international" in r["name"].lower() for r in records])
    in_metropolis = np.array([r["iata"] in metropolitan for r in records])
    weight = np.where(international, international_weight, 1.0) * np.where(
        in_metropolis, metropolitan_weight, 1.0
    )
    return Airports(
        iata=np.array([r["iata"] for r in records]),
        normal=geodetic_normal([r["lat"] for r in records], [r["lon"] for r in records]),
        weight=weight,
    )


def geodetic_normal(latitude_deg: ArrayLike, longitude_deg: ArrayLike) -> NDArray[np.float64]:
    """Unit ECEF normal of the WGS84 ellipsoid at geodetic latitude and longitude."""
    lat = np.radians(np.asarray(latitude_deg, dtype=float))
    lon = np.radians(np.asarray(longitude_deg, dtype=float))
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def sample_traffic(
    n_aircraft: int, rng: np.random.Generator, model: TrafficModel | None = None
) -> Traffic:
    """Draw ``n_aircraft`` aircraft of ``model`` (default :class:`TrafficModel`) as in the
    module docstring (Liu et al. 2023 sec. 5.1)."""
    model = TrafficModel() if model is None else model
    airports = load_airports(model.international_weight, model.metropolitan_weight)
    origin, destination = _sample_routes(airports, n_aircraft, rng, model)
    n_origin = airports.normal[origin]
    n_destination = airports.normal[destination]
    cos_angle = np.sum(n_origin * n_destination, axis=-1)
    tangent = n_destination - cos_angle[:, None] * n_origin
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    route_angle = np.arctan2(np.linalg.norm(np.cross(n_origin, n_destination), axis=-1), cos_angle)
    return Traffic(
        origin=airports.iata[origin],
        destination=airports.iata[destination],
        origin_normal=n_origin,
        route_tangent=tangent,
        route_angle_rad=route_angle,
        start_angle_rad=route_angle * rng.random(n_aircraft),
        height_km=rng.uniform(*model.height_range_km, n_aircraft),
        speed_mps=rng.uniform(*model.speed_range_m_s, n_aircraft),
    )


def _sample_routes(
    airports: Airports, n_routes: int, rng: np.random.Generator, model: TrafficModel
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Origin and destination indices by rejection sampling of the gravity model."""
    probability = airports.weight / airports.weight.sum()
    origins: list[NDArray[np.intp]] = []
    destinations: list[NDArray[np.intp]] = []
    accepted = 0
    while accepted < n_routes:
        origin = rng.choice(probability.size, _ROUTE_BATCH, p=probability)
        destination = rng.choice(probability.size, _ROUTE_BATCH, p=probability)
        cos_angle = np.sum(airports.normal[origin] * airports.normal[destination], axis=-1)
        distance_km = MEAN_RADIUS_KM * np.arccos(np.clip(cos_angle, -1.0, 1.0))
        preference = np.exp(-(distance_km - model.min_route_km) / model.route_scale_km)
        keep = (
            (distance_km >= model.min_route_km)
            & (distance_km <= model.max_route_km)
            & (rng.random(_ROUTE_BATCH) < preference)
        )
        origins.append(origin[keep])
        destinations.append(destination[keep])
        accepted += int(np.count_nonzero(keep))
    return np.concatenate(origins)[:n_routes], np.concatenate(destinations)[:n_routes]


def angle_from_origin(
    traffic: Traffic, t_s: ArrayLike, aircraft: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Central angle between each aircraft and its route's origin at time ``t_s``.

    Out and back along the route: with ``phase = (start + rate t) mod 2 Sigma``
    the angle is ``Sigma - |Sigma - phase|`` (``Sigma`` the route angle).
    ``t_s`` and ``aircraft`` (indices, default all) broadcast together.
    """
    index = np.arange(traffic.size) if aircraft is None else np.asarray(aircraft)
    route = traffic.route_angle_rad[index]
    phase = np.mod(
        traffic.start_angle_rad[index] + traffic.angular_rate_rad_s[index] * np.asarray(t_s),
        2.0 * route,
    )
    return route - np.abs(route - phase)


def geodetic_normals(
    traffic: Traffic, t_s: ArrayLike, aircraft: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Unit geodetic normals of aircraft at ``t_s``, shape ``broadcast(t_s, aircraft) + (3,)``."""
    index = np.arange(traffic.size) if aircraft is None else np.asarray(aircraft)
    angle = angle_from_origin(traffic, t_s, index)[..., None]
    return (
        np.cos(angle) * traffic.origin_normal[index] + np.sin(angle) * traffic.route_tangent[index]
    )


def positions_ecef_km(
    traffic: Traffic, t_s: ArrayLike, aircraft: ArrayLike | None = None
) -> NDArray[np.float64]:
    """WGS84 ECEF positions (km) of aircraft at ``t_s``, shaped as :func:`geodetic_normals`."""
    index = np.arange(traffic.size) if aircraft is None else np.asarray(aircraft)
    normal = geodetic_normals(traffic, t_s, index)
    height = np.broadcast_to(traffic.height_km[index], normal.shape[:-1])
    location = EarthLocation.from_geodetic(
        lon=np.arctan2(normal[..., 1], normal[..., 0]) * u.rad,
        lat=np.arctan2(normal[..., 2], np.hypot(normal[..., 0], normal[..., 1])) * u.rad,
        height=height * u.km,
        ellipsoid="WGS84",
    )
    return np.stack([location.x, location.y, location.z], axis=-1).to_value(u.km)


def horizontal_offsets_km(
    normal: ArrayLike, azimuth_rad: ArrayLike, distance_km: float
) -> NDArray[np.float64]:
    """ECEF displacements (km) of length ``distance_km`` in the local horizontal plane.

    ``normal`` ``(..., 3)`` are unit geodetic normals, ``azimuth_rad`` the directions
    clockwise from north (broadcast together): ``d (cos az n_north + sin az n_east)``
    with ``n_east = z x n / |z x n|`` and ``n_north = n x n_east`` (``z`` the ECEF polar
    axis; undefined at the poles).
    """
    normal = np.asarray(normal, dtype=float)
    azimuth = np.asarray(azimuth_rad, dtype=float)[..., None]
    east = np.cross([0.0, 0.0, 1.0], normal)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(normal, east)
    return distance_km * (np.cos(azimuth) * north + np.sin(azimuth) * east)
