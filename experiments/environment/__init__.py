"""Environment models for simulated attitude sensors (Cilden Guler et al. 2017 sec. 2.1).

* :mod:`.orbit`: TLE -> SGP4 (TEME) -> ECI (astropy GCRS) and ECEF (ITRS);
* :mod:`.sun`: apparent Sun direction from the satellite;
* :mod:`.geomagnetic`: IGRF field at the satellite (ppigrf);
* :mod:`.shadow`: cylindrical Earth shadow.
* :mod:`.disk_cache`: slow deterministic results (a scenario's geometry) cached on
  disk, once per machine.

Importing the package makes astropy's Earth-orientation data strictly offline:
the bundled ``astropy-iers-data`` table is used, never downloaded, and epochs
past its end only warn (degraded accuracy) instead of failing.
"""

from astropy.utils import iers

iers.conf.auto_download = False
iers.conf.auto_max_age = None
iers.conf.iers_degraded_accuracy = "warn"
