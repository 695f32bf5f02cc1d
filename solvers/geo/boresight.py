"""Boresight of a GEO broadcaster from SNRs at ground stations (Pimienta-Penalver and
Crassidis sec. IV.B, eq. 12), as snapshot estimators.

Each station's SNR is inverted through the link of Pimienta-Penalver and Crassidis eq. 7
(:mod:`attopt.formulations.geo_link`, satellite position and RF parameters known) for
the transmit gain and, through the main lobe of eq. 5
(:func:`attopt.solvers.snr.pattern_inverse.cos_from_gain`), for the off-boresight
angle ``theta_b``: the boresight ``B`` lies on the cone ``l . B = cos theta_b``
about the unit line of sight ``l`` from the satellite to the station
(:func:`epoch_cones`, from the :class:`~attopt.formulations.snr_problem.SnrEpoch`
of :func:`attopt.formulations.geo_link.geo_snr_epoch`).

* :data:`GEO_CONE` (registry ``geo_cone``): two cones with a common vertex
  meet in (at most) two directions (eq. 12)::

      rho = l_1 . l_2,
      eta_1 = (c_1 - rho c_2) / (1 - rho^2),  eta_2 = (c_2 - rho c_1) / (1 - rho^2),
      eta_3 = +-sqrt((1 - eta_1 c_1 - eta_2 c_2) / (1 - rho^2)),
      B = eta_1 l_1 + eta_2 l_2 + eta_3 (l_1 x l_2),

  and a third cone picks one of them.  Of the first three stations, the pair
  with the widest angle between its lines of sight is intersected and the
  third station selects (``selection_margin``: the rejected candidate's
  residual on the third cone minus the kept one's, ``cos`` units).  Fewer
  than three stations: the two candidates cannot be told apart
  (:class:`~attopt.formulations.errors.UnobservableError`).  A negative
  radicand (noisy SNRs: the cones miss each other) falls back to least
  squares over the same stations (``fell_back = 1``).
* :data:`GEO_LSQ` (registry ``geo_lsq``): every station, the constrained
  weighted least squares ``min sum ((l_k . B - c_k) / sigma_k)^2, |B| = 1`` of
  :func:`attopt.solvers.snr.boresight.estimate_boresight`, ``sigma_k`` the SNR
  noise mapped to ``cos theta_b``; coplanar lines of sight leave two
  boresights (:class:`~attopt.formulations.errors.UnobservableError`).

Solution.  The data determine the boresight only: the attitude is the
pointing (:func:`attopt.formulations.geo_link.attitude_pointing`) with the
yaw about the boresight arbitrary, that of the prior when one is given.  The
covariance is the first-order one of the cones used,
``(sum_k w_k g_k g_k^T)^-1`` with ``g_k = z x (A l_k)`` (the body-frame
gradient of ``cos theta_b``) and ``w_k = 1 / sigma_k^2``, which has an
INFINITE variance about the boresight (``z``):
:func:`attopt.formulations.snr_model.cramer_rao_bound`, so that
:meth:`attopt.solvers.results.Track.to_dataframe` reports NaN for yaw.  The
loss is ``1/2 sum ((l_k . B - c_k) / sigma_k)^2`` over the stations used.
Diagnostics: the boresight (:data:`BORESIGHT_DIAGNOSTICS`, the positions'
frame; :func:`estimated_boresight`), ``clamped_cos`` (gains clamped to the
main lobe) and, for ``geo_cone``, ``fell_back`` and ``selection_margin``.

The estimators use the epoch's lines of sight as given, which must be unit
vectors (as :func:`~attopt.formulations.geo_link.geo_snr_epoch` makes them):
normalising them again would change them by rounding.  Whether the stations
see the satellite is not in the epoch: :func:`check_elevations` rejects a
station with the satellite below its horizon.  :func:`rf_sensitivity`
measures the boresight error when the solver is given wrong RF parameters
(Pimienta-Penalver and Crassidis Fig. 6).
"""

from __future__ import annotations

import dataclasses
import itertools
from abc import abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import AttoptError, InvalidObservationError, UnobservableError
from attopt.formulations.geo_link import (
    BORESIGHT_BODY,
    GARUDA1,
    GeoLink,
    attitude_pointing,
    elevation_rad,
    geo_snr_db,
    geo_snr_epoch,
)
from attopt.formulations.passes import Prior
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import cramer_rao_bound
from attopt.formulations.snr_problem import SnrEpoch, content_issue
from attopt.solvers.estimator import SnapshotEstimator
from attopt.solvers.results import Track
from attopt.solvers.snapshot_sequence import EpochEstimate, WarmStart, solve_in_sequence
from attopt.solvers.snr.boresight import estimate_boresight
from attopt.solvers.snr.driver import snr_epochs, start_attitude
from attopt.solvers.snr.pattern_inverse import cos_from_gain

Array = NDArray[np.float64]

MIN_STATIONS = 3
"""Two cones meet in two directions; a third cone is needed to choose (Pimienta-Penalver
and Crassidis sec. IV.B)."""
UNIT_TOLERANCE = 1e-12
"""Largest ``| |l| - 1 |`` of a line of sight the estimators accept."""
BORESIGHT_DIAGNOSTICS = ("boresight_x", "boresight_y", "boresight_z")
"""Diagnostics holding the estimated boresight (frame of the positions)."""


@dataclass(frozen=True)
class StationCones:
    """Cones ``l_k . B = c_k`` of ``m`` stations (frame of the positions)."""

    los: Array
    """``(m, 3)`` unit lines of sight satellite -> station."""
    cos_off_boresight: Array
    """``(m,)`` ``c_k = cos theta_bk`` from the SNRs."""
    sigma_cos: Array
    """``(m,)`` standard deviation of ``c_k`` from the SNR noise."""
    clamped: int
    """Gains outside the main lobe's range, clamped to it (noise or wrong RF parameters)."""

    def take(self, rows: Sequence[int] | slice) -> StationCones:
        """The cones of ``rows``."""
        return dataclasses.replace(
            self,
            los=self.los[rows],
            cos_off_boresight=self.cos_off_boresight[rows],
            sigma_cos=self.sigma_cos[rows],
        )


@dataclass(frozen=True)
class BoresightFit:
    """A boresight and the cones it was fitted to (those the covariance and loss use)."""

    direction: Array
    cones: StationCones
    diagnostics: dict[str, float]


def check_elevations(
    stations_km: ArrayLike, stations_up: ArrayLike, satellite_km: ArrayLike
) -> None:
    """Raise :class:`InvalidObservationError` naming the stations with the satellite below
    their horizon (no line of sight)."""
    elevation = elevation_rad(stations_km, stations_up, satellite_km)
    below = np.flatnonzero(~(elevation >= 0.0))
    if below.size:
        raise InvalidObservationError(
            f"station(s) {below.tolist()} have the satellite below the horizon (elevation "
            f"{np.degrees(elevation[below]).round(2).tolist()} deg): no line of sight"
        )


def epoch_cones(epoch: SnrEpoch) -> StationCones:
    """Invert eq. 7 at each of the epoch's stations for ``cos theta_b`` (module docstring)."""
    los = epoch.los_orbit
    if np.any(np.abs(np.linalg.norm(los, axis=1) - 1.0) > UNIT_TOLERANCE):
        raise InvalidObservationError(
            "the boresight estimators need unit lines of sight (geo_snr_epoch's)"
        )
    gain = epoch.snr_db - epoch.p0_dbw + epoch.noise_dbw
    cosine, slope, clamped = cos_from_gain(epoch.pattern, gain)
    return StationCones(los, cosine, np.abs(slope) * epoch.sigma_db, clamped)


def _pair_candidates(los: Array, cosine: Array) -> tuple[Array, float]:
    """The two directions on both cones (eq. 12) and the radicand ``eta_3^2``."""
    rho = float(los[0] @ los[1])
    sine2 = 1.0 - rho * rho
    eta1 = (cosine[0] - rho * cosine[1]) / sine2
    eta2 = (cosine[1] - rho * cosine[0]) / sine2
    radicand = (1.0 - eta1 * cosine[0] - eta2 * cosine[1]) / sine2
    eta3 = np.sqrt(max(radicand, 0.0))
    base = eta1 * los[0] + eta2 * los[1]
    normal = np.cross(los[0], los[1])
    return np.stack([base + eta3 * normal, base - eta3 * normal]), radicand


def intersect_cones(cones: StationCones) -> BoresightFit:
    """Boresight from the first three stations' cones (eq. 12), least squares if they miss."""
    if cones.los.shape[0] < MIN_STATIONS:
        raise UnobservableError(
            f"{cones.los.shape[0]} station(s): cone intersection needs three; two cones about "
            "different lines of sight meet in two directions and nothing chooses between them"
        )
    three = cones.take(slice(0, MIN_STATIONS))
    los, cosine = three.los, three.cos_off_boresight
    pairs = list(itertools.combinations(range(MIN_STATIONS), 2))
    i, j = max(pairs, key=lambda p: np.linalg.norm(np.cross(los[p[0]], los[p[1]])))
    (k,) = set(range(MIN_STATIONS)) - {i, j}
    candidates, radicand = _pair_candidates(los[[i, j]], cosine[[i, j]])
    if radicand < 0.0:
        fallback = fit_cones(three)
        diagnostics = {**fallback.diagnostics, "fell_back": 1.0, "selection_margin": np.nan}
        return dataclasses.replace(fallback, diagnostics=diagnostics)
    residual = np.abs(candidates @ los[k] - cosine[k])
    keep = int(np.argmin(residual))
    direction = candidates[keep] / np.linalg.norm(candidates[keep])
    margin = float(residual[1 - keep] - residual[keep])
    diagnostics = {"fell_back": 0.0, "selection_margin": margin}
    return BoresightFit(direction, three.take([i, j]), diagnostics)


def fit_cones(cones: StationCones) -> BoresightFit:
    """Constrained weighted least squares over every station's cone (module docstring)."""
    m = cones.los.shape[0]
    if m < MIN_STATIONS:
        raise UnobservableError(
            f"{m} station(s): the boresight needs three cones (two leave a two-fold ambiguity)"
        )
    prior = cones.los.mean(axis=0)
    estimate = estimate_boresight(cones.los, cones.cos_off_boresight, cones.sigma_cos, prior)
    if estimate.two_fold:
        raise UnobservableError(
            "the stations' lines of sight are coplanar: two boresights fit the SNRs equally well"
        )
    return BoresightFit(estimate.direction, cones, {})


def pointing_covariance(attitude: Rotation, cones: StationCones) -> Array:
    """``(sum_k w_k g_k g_k^T)^-1``, ``g_k = z x (A l_k)``: infinite about the boresight."""
    gradient = np.cross(BORESIGHT_BODY, cones.los @ attitude.as_matrix().T)
    weights = cones.sigma_cos**-2.0
    return cramer_rao_bound((gradient.T * weights) @ gradient)


def cone_loss(cones: StationCones, direction: Array) -> float:
    """``1/2 sum ((l_k . B - c_k) / sigma_k)^2``."""
    residual = (cones.los @ direction - cones.cos_off_boresight) / cones.sigma_cos
    return 0.5 * float(residual @ residual)


def estimated_boresight(track: Track) -> Array:
    """``(N, 3)`` boresights of a boresight estimator's track (NaN where invalid)."""
    return np.stack([track.diagnostics[name] for name in BORESIGHT_DIAGNOSTICS], axis=1)


@dataclass(frozen=True, repr=False)
class BoresightEstimator(SnapshotEstimator):
    """A snapshot estimator of the boresight from a GEO link epoch (module docstring)."""

    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (SnrMeasurement,)
    diagnostic_names: ClassVar[tuple[str, ...]]

    @abstractmethod
    def fit(self, cones: StationCones) -> BoresightFit:
        """The boresight of the epoch's cones."""

    def solve_sequence(
        self, snapshots: Sequence[Snapshot | None], prior: Rotation | Prior | None = None
    ) -> Track:
        """Each epoch on its own; ``prior`` gives the yaw about the boresight."""
        return solve_in_sequence(
            self.name,
            snr_epochs(self, snapshots),
            start_attitude(prior),
            WarmStart(enabled=False),
            self.diagnostic_names,
            content_issue,
            self._estimate,
        )

    def _estimate(self, epoch: SnrEpoch, reference: Rotation | None) -> EpochEstimate:
        try:
            cones = epoch_cones(epoch)
            fit = self.fit(cones)
        except AttoptError as exc:
            return EpochEstimate.failed(str(exc), {}, type(exc))
        attitude = attitude_pointing(fit.direction, reference)
        diagnostics = {
            **dict(zip(BORESIGHT_DIAGNOSTICS, fit.direction.tolist(), strict=True)),
            **fit.diagnostics,
            "clamped_cos": float(cones.clamped),
        }
        return EpochEstimate(
            attitude,
            pointing_covariance(attitude, fit.cones),
            cone_loss(fit.cones, fit.direction),
            diagnostics,
        )


@dataclass(frozen=True, repr=False)
class ConeIntersection(BoresightEstimator):
    """Registry entry ``geo_cone`` (module docstring)."""

    name: str = "geo_cone"
    description: str = (
        "boresight by intersecting three stations' SNR cones, least squares when they miss "
        "(Pimienta-Penalver and Crassidis sec. IV.B, eq. 12); yaw unobservable"
    )
    diagnostic_names: ClassVar[tuple[str, ...]] = (
        *BORESIGHT_DIAGNOSTICS,
        "fell_back",
        "selection_margin",
        "clamped_cos",
    )

    def fit(self, cones: StationCones) -> BoresightFit:
        return intersect_cones(cones)


@dataclass(frozen=True, repr=False)
class LeastSquaresBoresight(BoresightEstimator):
    """Registry entry ``geo_lsq`` (module docstring)."""

    name: str = "geo_lsq"
    description: str = (
        "boresight by constrained weighted least squares over every station's SNR cone "
        "(Pimienta-Penalver and Crassidis sec. IV.B); yaw unobservable"
    )
    diagnostic_names: ClassVar[tuple[str, ...]] = (*BORESIGHT_DIAGNOSTICS, "clamped_cos")

    def fit(self, cones: StationCones) -> BoresightFit:
        return fit_cones(cones)


GEO_CONE = ConeIntersection()
GEO_LSQ = LeastSquaresBoresight()


def boresight_error_rad(estimate: ArrayLike, truth: ArrayLike) -> float:
    """Angle between two boresight directions (rad), accurate at any angle."""
    a, b = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b))


@dataclass(frozen=True)
class RfSensitivity:
    """Boresight errors (rad) on a grid of assumed transmit powers x dish diameters."""

    transmit_power_w: Array
    dish_diameter_m: Array
    error_rad: Array
    """``(n_power, n_diameter)``."""
    fell_back: NDArray[np.bool_]
    """Where cone intersection fell back to least squares."""


SENSITIVITY_METHODS: dict[str, BoresightEstimator] = {
    "cone_intersection": GEO_CONE,
    "least_squares": GEO_LSQ,
}
"""The two methods of Pimienta-Penalver and Crassidis sec. IV.B by the names of its Fig. 6."""


def rf_sensitivity(
    truth: Rotation,
    satellite_km: ArrayLike,
    stations_km: ArrayLike,
    stations_up: ArrayLike,
    transmit_power_w: ArrayLike,
    dish_diameter_m: ArrayLike,
    link: GeoLink = GARUDA1,
    method: str = "cone_intersection",
) -> RfSensitivity:
    """Boresight error with noise-free SNRs of ``link`` inverted with wrong ``P_t`` and ``D``.

    Pimienta-Penalver and Crassidis Fig. 6: the SNRs are those of the true attitude and ``link``;
    the solver (:data:`SENSITIVITY_METHODS`) assumes each (``P_t``, ``D``)
    pair of the grid instead.
    """
    if method not in SENSITIVITY_METHODS:
        raise InvalidObservationError(
            f"method must be one of {sorted(SENSITIVITY_METHODS)}, got {method!r}"
        )
    estimator = SENSITIVITY_METHODS[method]
    check_elevations(stations_km, stations_up, satellite_km)
    snr = geo_snr_db(truth.as_matrix(), satellite_km, stations_km, link)
    true_boresight = truth.inv().apply(BORESIGHT_BODY)
    powers = np.asarray(transmit_power_w, dtype=float)
    diameters = np.asarray(dish_diameter_m, dtype=float)
    error = np.empty((powers.size, diameters.size))
    fell_back = np.zeros(error.shape, dtype=bool)
    for (a, power), (b, diameter) in itertools.product(enumerate(powers), enumerate(diameters)):
        assumed = dataclasses.replace(link, transmit_power_w=power, dish_diameter_m=diameter)
        epoch = geo_snr_epoch(snr, satellite_km, stations_km, 1.0, assumed)
        solution = estimator.solve(Snapshot.of(SnrMeasurement(epoch)))
        direction = [solution.diagnostics[name] for name in BORESIGHT_DIAGNOSTICS]
        error[a, b] = boresight_error_rad(direction, true_boresight)
        fell_back[a, b] = solution.diagnostics.get("fell_back", 0.0) == 1.0
    return RfSensitivity(powers, diameters, error, fell_back)
