"""Figures of a :class:`~attopt.solvers.results.Track`: error or estimate with +/-3 sigma.

The one plotting routine of estimates; the experiments' reports draw their
per-method figures with it.  matplotlib is imported with the non-interactive
Agg back-end (figures are written to files; no display is needed).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.solvers.results import AXES, attitude_errors

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from attopt.solvers.results import Track

AXIS_NAMES = ("roll (x)", "pitch (y)", "yaw (z)")


def plot_track(track: Track, truth: Rotation | None = None, ax: Any = None) -> Figure:
    """Per body axis: the error in degrees against ``truth`` with its +/-3 sigma band, or,
    without ``truth``, the 3-2-1 Euler angle with the band around it.

    ``ax``: three matplotlib axes to draw into (default: a new figure).
    Invalid epochs and unobservable axes leave gaps.  Returns the figure.
    """
    if ax is None:
        figure, ax = plt.subplots(3, 1, sharex=True, figsize=(8.0, 6.5))
    else:
        figure = ax[0].figure
    n = len(track)
    t = np.arange(n, dtype=float) if track.t is None else np.asarray(track.t, dtype=float)
    sigma = track.sigma_deg
    if truth is not None:
        centre = np.degrees(attitude_errors(track.quaternion, truth))
        centre[~np.isfinite(sigma)] = np.nan
        label, band_centre = "error", np.zeros_like(centre)
    else:
        centre = np.full((n, 3), np.nan)
        if track.valid.any():
            euler = Rotation.from_quat(track.quaternion[track.valid]).inv().as_euler("ZYX")
            centre[track.valid] = np.degrees(euler[:, ::-1])  # roll, pitch, yaw
        label, band_centre = "estimate", centre
    for i, axis in enumerate(ax):
        axis.plot(t, centre[:, i], lw=0.8, label=f"{track.method} {label}")
        axis.fill_between(
            t,
            band_centre[:, i] - 3 * sigma[:, i],
            band_centre[:, i] + 3 * sigma[:, i],
            alpha=0.25,
            lw=0,
            label="+/-3 sigma",
        )
        axis.set_ylabel(f"{AXIS_NAMES[i]} (deg)")
        axis.grid(True, alpha=0.3)
    ax[0].legend(loc="upper right", fontsize="small")
    ax[-1].set_xlabel("t (s)" if track.t is not None else "epoch")
    title = "error" if truth is not None else "3-2-1 Euler angles"
    ax[0].set_title(f"{track.method}: {title} with +/-3 sigma per body axis ({', '.join(AXES)})")
    figure.tight_layout()
    return figure
