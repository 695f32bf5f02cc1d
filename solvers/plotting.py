"""Figures of estimates: per body axis an error or estimate with its +/-3 sigma band.

The one plotting routine of estimates.  :func:`plot_axes` draws from arrays
(times, errors or estimates, sigmas per axis); :meth:`Track.plot
<attopt.solvers.results.Track.plot>` (:func:`plot_track`) and the experiments'
reports (:mod:`attopt.experiments.reporting.figures`) call it.  matplotlib is
imported with the non-interactive Agg back-end (figures are written to files;
no display is needed).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from attopt.solvers.results import AXES, attitude_errors

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from attopt.solvers.results import Track

AXIS_NAMES = ("roll (x)", "pitch (y)", "yaw (z)")


def plot_axes(
    t: ArrayLike,
    values: ArrayLike,
    sigma: ArrayLike,
    *,
    label: str,
    estimate: bool = False,
    ax: Any = None,
    unit: str = "deg",
    names: Sequence[str] = AXIS_NAMES,
    color: str | None = None,
) -> Figure:
    """Per axis ``i``: ``values[:, i]`` against ``t`` with the band ``+/- 3 sigma[:, i]``,
    around zero (``values`` are errors) or around the values (``estimate``).

    ``values`` and ``sigma`` are ``(N, k)``, one panel per column; NaN leaves a
    gap.  ``ax``: ``k`` matplotlib axes to draw into (default: a new figure).
    Drawing several estimators into the same axes overlays them.  Returns the figure.
    """
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    if ax is None:
        figure, ax = plt.subplots(values.shape[1], 1, sharex=True, figsize=(8.0, 6.5))
    else:
        figure = ax[0].figure
    centre = values if estimate else np.zeros_like(values)
    for i, axis in enumerate(ax):
        (line,) = axis.plot(t, values[:, i], lw=0.8, color=color, label=label)
        axis.fill_between(
            t,
            centre[:, i] - 3 * sigma[:, i],
            centre[:, i] + 3 * sigma[:, i],
            color=line.get_color(),
            alpha=0.25,
            lw=0,
            label=f"{label} +/-3 sigma",
        )
        axis.set_ylabel(f"{names[i]} ({unit})")
        axis.grid(True, alpha=0.3)
    ax[0].legend(loc="upper right", fontsize="small")
    return figure


def plot_track(track: Track, truth: Rotation | None = None, ax: Any = None) -> Figure:
    """Per body axis: the error in degrees against ``truth`` with its +/-3 sigma band, or,
    without ``truth``, the 3-2-1 Euler angle with the band around it.

    ``ax``: three matplotlib axes to draw into (default: a new figure).
    Invalid epochs and unobservable axes leave gaps.  Returns the figure.
    """
    n = len(track)
    t = np.arange(n, dtype=float) if track.t is None else np.asarray(track.t, dtype=float)
    sigma = track.sigma_deg
    if truth is not None:
        values = np.degrees(attitude_errors(track.quaternion, truth))
        values[~np.isfinite(sigma)] = np.nan
    else:
        values = np.full((n, 3), np.nan)
        if track.valid.any():
            euler = Rotation.from_quat(track.quaternion[track.valid]).inv().as_euler("ZYX")
            values[track.valid] = np.degrees(euler[:, ::-1])  # roll, pitch, yaw
    kind = "error" if truth is not None else "estimate"
    figure = plot_axes(
        t, values, sigma, label=f"{track.method} {kind}", estimate=truth is None, ax=ax
    )
    axes = figure.axes[:3] if ax is None else ax
    axes[-1].set_xlabel("t (s)" if track.t is not None else "epoch")
    title = "error" if truth is not None else "3-2-1 Euler angles"
    axes[0].set_title(f"{track.method}: {title} with +/-3 sigma per body axis ({', '.join(AXES)})")
    figure.tight_layout()
    return figure
