"""Pimienta-Penalver and Crassidis: attitude of a GEO broadcaster from SNRs at ground stations.

* :mod:`.m2m4`: second- and fourth-order moment SNR estimator (eqs. 8-11, Table 3);
* :mod:`.los`: line of sight by a search along the GEO belt and least squares (sec. IV.A);
* :mod:`.boresight`: the snapshot estimators ``geo_cone`` (cone intersection,
  sec. IV.B, eq. 12) and ``geo_lsq`` (least-squares boresight) of the pointing;
* :mod:`.manoeuvre`: manoeuvre detection and filter re-initialisation (sec. V.B).
"""

from __future__ import annotations

from attopt.solvers.geo.boresight import GEO_CONE, GEO_LSQ

ESTIMATORS = (GEO_CONE, GEO_LSQ)
"""The boresight estimators (Pimienta-Penalver and Crassidis sec. IV.B)."""
