"""Your own gyro samples (10 Hz) and vector measurements (1 Hz, between the gyro's
samples) through the MEKF, its RTS smoother and the factor-graph smoother.

The data are simulated here so that the script runs anywhere; replace the
"your data" block with your recording (sample times, mean rates over each
sample interval, measurement times, body and reference vectors, sigmas). The
figure shows each estimator's error with its own +/-3 sigma per body axis.
Run: ``python examples/own_gyro_pass.py [output_dir]``.
"""

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

import attopt

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
rng = np.random.default_rng(7)

# --- your data (simulated: a slow tumble, a MEMS gyro, a Sun sensor and a magnetometer)
t_gyro = np.arange(0.0, 600.0 + 1e-9, 0.1)
truth_gyro = Rotation.from_rotvec(-np.outer(t_gyro, [0.002, -0.004, 0.003])) * Rotation.random(
    random_state=rng
)
gyro = attopt.simulate_gyro(t_gyro, truth_gyro, attopt.MEMS_GYRO, rng)  # or your samples
t = np.arange(0.35, 600.0, 1.0)  # measurement times, not gyro sample times
truth = Slerp(t_gyro, truth_gyro)(t)
reference = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])  # Sun, magnetic field (inertial)
sigma = np.radians([0.05, 0.5])
body = np.stack([truth.apply(r) for r in reference], axis=1)
body = body + sigma[None, :, None] * rng.standard_normal(body.shape)

# --- attopt
record = attopt.GyroRecord(t_gyro, gyro.samples.rates, attopt.MEMS_GYRO)
start = Rotation.from_rotvec(np.radians([3.0, -2.0, 4.0])) * truth_gyro[0]
prior = attopt.Prior(start, np.radians(5.0) ** 2 * np.eye(3))
pass_ = attopt.Pass.from_vectors(t, body, reference, sigma, gyro=record, prior=prior)
runs = attopt.run_estimators(pass_, ["mekf", "rts", "fg_batch"])
for name, run in runs.items():
    errors = run.track.to_dataframe(truth)
    rms = np.sqrt((errors[["err_x_deg", "err_y_deg", "err_z_deg"]][t > 60] ** 2).mean())
    print(run.track, f"{run.seconds:.2f} s; RMS after 60 s (deg):", rms.round(4).tolist())
    run.track.plot(truth).savefig(out / f"{name}_errors.png", dpi=90)
