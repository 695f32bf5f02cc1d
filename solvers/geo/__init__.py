"""Seed 004: attitude of a GEO broadcaster from SNRs at ground stations.

* :mod:`.m2m4`: second- and fourth-order moment SNR estimator (eqs. 8-11, Table 3);
* :mod:`.los`: line of sight by a search along the GEO belt and least squares (sec. IV.A);
* :mod:`.boresight`: boresight by cone intersection and least squares (sec. IV.B, eq. 12).
"""
