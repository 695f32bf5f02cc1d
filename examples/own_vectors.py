"""Your own vector pairs, solved for an attitude and its covariance.

Three sensors measure known reference directions in the body frame (a star
tracker's boresight star, a Sun sensor and a magnetometer), each with its own
noise. QUEST solves Wahba's problem; the MAP NLP solves the same snapshot from
the symbolic measurement model; the Cramer-Rao bound says how well any unbiased
estimator can do. Run: ``python examples/own_vectors.py``.
"""

import numpy as np

import attopt

# Your data: reference directions (inertial), measured body vectors, per-sensor sigmas.
reference = np.array([[0.0, 0.0, 1.0], [0.8, 0.6, 0.0], [0.3, -0.5, 0.81]])
sigma = np.radians([0.01, 0.1, 0.5])  # star tracker, Sun sensor, magnetometer (rad)
truth = attopt.attitude_from_euler321(*np.radians([30.0, -10.0, 5.0]))
rng = np.random.default_rng(1)
body = truth.apply(reference) + sigma[:, None] * rng.standard_normal((3, 3))

snapshot = attopt.Snapshot.from_vectors(body, reference, sigma=sigma)
for name in ("quest", "map_nlp"):
    solution = attopt.estimator(name).solve(snapshot)
    print(solution)
    print(solution.to_dataframe(truth)[["err_x_deg", "err_y_deg", "err_z_deg", "nees"]])
bound = attopt.crb(snapshot, truth)
print("Cramer-Rao bound, sigma per body axis (deg):", np.degrees(np.sqrt(np.diag(bound))))
print("yaw, pitch, roll (deg):", np.degrees(attopt.euler321_from_attitude(solution.attitude)))
