"""The reports' figures: errors against time with +/-3 sigma per axis, saved next to ``report.md``.

Every error figure is drawn by :func:`attopt.solvers.plotting.plot_axes`, the
routine behind :meth:`Track.plot <attopt.solvers.results.Track.plot>`; the
stored rows give its arrays (times, error and sigma columns).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from attopt.experiments.reporting.statistics import AXES
from attopt.solvers.plotting import AXIS_NAMES, plot_axes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

ERRORS = tuple(f"err_{a}_deg" for a in AXES)
SIGMAS = tuple(f"sigma_{a}_deg" for a in AXES)
DPI = 110


def first_trial(rows: pd.DataFrame) -> pd.DataFrame:
    """The rows of the first setting's first trial (what the time-series figures draw)."""
    if "setting_index" in rows:
        rows = rows[rows["setting_index"] == rows["setting_index"].min()]
    return rows[rows["trial_index"] == rows["trial_index"].min()]


def error_figure(
    frames: Mapping[str, pd.DataFrame],
    title: str,
    *,
    values: Sequence[str] = ERRORS,
    sigmas: Sequence[str] = SIGMAS,
    time: str = "t",
    unit: str = "deg",
    names: Sequence[str] = AXIS_NAMES,
    xlabel: str = "t (s)",
    spans: Iterable[tuple[float, float, str]] = (),
    fit_from: float | None = None,
    ax: Any = None,
) -> Figure:
    """Per axis, the columns ``values`` of every frame (label: its key) against ``time``
    with the +/-3 ``sigmas`` band, overlaid; ``spans`` ``(start, end, label)`` shaded;
    with ``fit_from`` the y axes fitted to the values and bands from that time on."""
    figure, created = None, ax is None
    for label, frame in frames.items():
        figure = plot_axes(
            frame[time],
            frame[list(values)],
            frame[list(sigmas)],
            label=label,
            ax=ax,
            unit=unit,
            names=names,
        )
        ax = figure.axes if ax is None else ax
    for start, end, label in spans:
        for i, axis in enumerate(ax):
            axis.axvspan(start, end, color="0.9", zorder=0, label=label if i == 0 else None)
    if fit_from is not None:
        later = [f[f[time] >= fit_from] for f in frames.values()]
        for i, axis in enumerate(ax):
            extent = np.concatenate(
                [np.abs(f[values[i]].to_numpy(dtype=float)) for f in later]
                + [3 * f[sigmas[i]].to_numpy(dtype=float) for f in later]
            )
            extent = extent[np.isfinite(extent)]
            if extent.size and extent.max() > 0:
                axis.set_ylim(-1.15 * extent.max(), 1.15 * extent.max())
    if created and len(frames) > 1:  # overlays: the legend beside the panels
        figure.set_size_inches(10.5, 6.5)
        ax[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    else:
        ax[0].legend(loc="upper right", fontsize="small")
    ax[0].set_title(title, fontsize=10)
    ax[-1].set_xlabel(xlabel)
    return figure


def save_figure(figure: Figure, out_dir: Path, name: str) -> str:
    """Write ``figure`` to ``out_dir / name``, close it and return ``name``."""
    figure.tight_layout()
    figure.savefig(Path(out_dir) / name, dpi=DPI)
    plt.close(figure)
    return name


def image_links(names: Iterable[str]) -> str:
    """Markdown image links to the figure files ``names``."""
    return "\n".join(f"![{name}]({name})" for name in names)
