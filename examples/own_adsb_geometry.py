"""Your own ADS-B-like geometry: any number of receive antennas, aircraft in view,
the Cramer-Rao bound of one epoch's SNRs and the NLP's solution.

Three helix antennas (cos^6 pattern, 14.5 dBi peak, main lobe down to 4 dBi)
point 40 deg off nadir in three directions; aircraft transponders are seen
1000-2000 km away. Replace the geometry block with yours (boresights in the
body frame, lines of sight in the reference frame, slant ranges or powers).
Run: ``python examples/own_adsb_geometry.py``.
"""

import numpy as np

import attopt

rng = np.random.default_rng(3)
truth = attopt.attitude_from_euler321(*np.radians([4.0, -2.0, 3.0]))

# --- your geometry: boresights (body), lines of sight (orbit frame), ranges
tilt, azimuths = np.radians(40.0), np.radians([0.0, 120.0, 240.0])
boresights = np.column_stack(
    [np.sin(tilt) * np.cos(azimuths), np.sin(tilt) * np.sin(azimuths), np.full(3, np.cos(tilt))]
)
pattern = attopt.CosinePowerPattern(peak_gain=14.46, exponent=6.0, min_gain_dbi=4.0)
antenna = np.repeat(np.arange(3), 12)
offsets = rng.uniform(0.0, 0.6 * pattern.max_off_boresight_rad, antenna.size)
turn = rng.uniform(0.0, 2.0 * np.pi, antenna.size)
body = np.cos(offsets)[:, None] * boresights[antenna] + np.sin(offsets)[:, None] * np.cross(
    boresights[antenna], np.column_stack([np.cos(turn), np.sin(turn), np.zeros_like(turn)])
)
los = truth.inv().apply(body / np.linalg.norm(body, axis=1, keepdims=True))
ranges = rng.uniform(1.0e6, 2.0e6, antenna.size)

# --- attopt: predict the true SNRs, add 1 dB noise, bound and solve
epoch = attopt.SnrEpoch.from_ranges(
    np.full(antenna.size, 20.0), los, antenna, boresights, ranges, pattern, attopt.LinkBudget()
)
true_snr = attopt.SnrMeasurement(epoch).predict(truth)[0][0]
measured = attopt.SnrEpoch.from_ranges(
    true_snr + rng.standard_normal(true_snr.size),
    los,
    antenna,
    boresights,
    ranges,
    pattern,
    threshold_db=-np.inf,
)
snapshot = attopt.Snapshot.of(attopt.SnrMeasurement(measured))
bound = np.degrees(np.sqrt(np.diag(attopt.crb(snapshot, truth))))
solution = attopt.estimator("nlp").solve(snapshot)
print("SNRs per antenna:", np.bincount(antenna).tolist(), "- CRB sigma (deg):", bound.round(3))
print(solution)
print(solution.to_dataframe(truth)[["err_x_deg", "err_y_deg", "err_z_deg", "nees"]])
