"""Pictures of a run: the map with the odometry, localized and true trajectories (like the
paper's Fig. 9–11), and error-over-time plots. matplotlib's Agg canvas, no pyplot state,
so it works headless and from threads.

Maps are plain arrays so this module does not depend on :mod:`icploc.maps`: ``lines``
(K, 4) as x0 y0 x1 y1, ``points`` (M, 2), or an occupancy ``grid`` image with its
``extent``. A map object with ``.lines`` (and optionally ``.points``) is accepted as ``map``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.trajectory import Trajectory

__all__ = ["TrajLike", "plot_errors", "plot_run", "save_figure"]

TrajLike = Trajectory | ArrayLike  #: a Trajectory or an (N, 2+) array of x, y[, theta]

_STYLE: dict[str, dict[str, Any]] = {
    "truth": {"color": "0.1", "lw": 0.9, "ls": "-", "label": "truth", "zorder": 4},
    "odometry": {"color": "tab:red", "lw": 1.1, "ls": "--", "label": "odometry", "zorder": 2},
    "localized": {"color": "tab:blue", "lw": 1.8, "ls": "-", "label": "localization", "zorder": 3},
}


def _xy(t: TrajLike) -> NDArray[np.float64]:
    if isinstance(t, Trajectory):
        return t.sorted().xy
    a = np.asarray(t, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] < 2:
        raise ValueError(
            f"a trajectory must be a Trajectory or an (N, 2+) array, got shape {a.shape}"
        )
    return a[:, :2]


def _figure(figsize: tuple[float, float]) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=100)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 150) -> None:
    """Save a figure (PNG, SVG or PDF by extension)."""
    fig.savefig(os.fspath(path), dpi=dpi, bbox_inches="tight")


def plot_run(
    path: str | os.PathLike[str] | None = None,
    *,
    map: Any = None,  # noqa: A002 - the natural name here
    lines: ArrayLike | None = None,
    points: ArrayLike | None = None,
    grid: ArrayLike | None = None,
    extent: Sequence[float] | None = None,
    truth: TrajLike | None = None,
    odometry: TrajLike | None = None,
    localized: TrajLike | None = None,
    others: Mapping[str, TrajLike] | None = None,
    scan_points: ArrayLike | None = None,
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 7.0),
    mark_ends: bool = True,
    dpi: int = 150,
) -> Any:
    """Draw the map and the trajectories; save to ``path`` if given; return the Figure.

    ``grid``: an occupancy image (rows from the top, values 0 free … 1 or 100 occupied,
    negative unknown) drawn with ``extent`` = (xmin, xmax, ymin, ymax). ``others``: extra
    named trajectories. ``scan_points``: (M, 2) world points of a scan to overlay.
    Start points are marked with a circle and end points with a square.
    """
    if map is not None:
        if lines is None and getattr(map, "lines", None) is not None:
            lines = map.lines
        if points is None and getattr(map, "points", None) is not None:
            points = map.points
    fig = _figure(figsize)
    ax = fig.add_subplot(1, 1, 1)
    if grid is not None:
        g = np.asarray(grid, dtype=np.float64)
        if g.ndim != 2:
            raise ValueError(f"grid must be a 2-D image, got shape {g.shape}")
        top = 100.0 if np.nanmax(g) > 1.0 else 1.0
        img = np.where(g < 0, 0.5, 1.0 - np.clip(g / top, 0.0, 1.0))
        ext = (
            tuple(extent)
            if extent is not None
            else (0.0, float(g.shape[1]), 0.0, float(g.shape[0]))
        )
        ax.imshow(
            img,
            cmap="gray",
            vmin=0.0,
            vmax=1.0,
            extent=ext,
            origin="upper",
            interpolation="nearest",
        )
    if lines is not None:
        L = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
        if len(L):
            from matplotlib.collections import LineCollection

            segs = L.reshape(-1, 2, 2)
            ax.add_collection(LineCollection(list(segs), colors="k", linewidths=1.2, label="map"))
            ax.update_datalim(L.reshape(-1, 2))
    if points is not None:
        P = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if len(P):
            ax.plot(
                P[:, 0], P[:, 1], ",", color="0.35", label="map points" if lines is None else None
            )
    if scan_points is not None:
        S = np.asarray(scan_points, dtype=np.float64).reshape(-1, 2)
        ax.plot(S[:, 0], S[:, 1], ".", ms=2.0, color="tab:green", label="scan")
    trajs: list[tuple[str, TrajLike, dict[str, Any]]] = []
    for name, t in (("truth", truth), ("odometry", odometry), ("localized", localized)):
        if t is not None:
            trajs.append((name, t, dict(_STYLE[name])))
    cycle = ["tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan"]
    for k, (name, t) in enumerate((others or {}).items()):
        trajs.append(
            (name, t, {"color": cycle[k % len(cycle)], "lw": 1.1, "ls": "-", "label": name})
        )
    for _, t, st in trajs:
        xy = _xy(t)
        if len(xy) == 0:
            continue
        ax.plot(xy[:, 0], xy[:, 1], **st)
        if mark_ends:
            z = st.get("zorder", 2) + 0.5
            ax.plot(xy[0, 0], xy[0, 1], "o", color=st["color"], ms=6, mfc="none", zorder=z)
            ax.plot(xy[-1, 0], xy[-1, 1], "s", color=st["color"], ms=6, mfc="none", zorder=z)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3, alpha=0.5)
    if title:
        ax.set_title(title)
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc="best", fontsize=8, framealpha=0.8)
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig


def plot_errors(
    path: str | os.PathLike[str] | None,
    stamps: ArrayLike,
    position_errors: ArrayLike,
    heading_errors: ArrayLike | None = None,
    *,
    title: str | None = None,
    figsize: tuple[float, float] = (8.0, 4.0),
    dpi: int = 150,
) -> Any:
    """Position error (cm) and, if given, heading error (deg) over time."""
    t = np.asarray(stamps, dtype=np.float64)
    e = np.asarray(position_errors, dtype=np.float64)
    if t.shape != e.shape:
        raise ValueError(f"stamps {t.shape} and errors {e.shape} differ in shape")
    fig = _figure(figsize)
    ax = fig.add_subplot(1, 1, 1)
    t0 = float(t[0]) if len(t) else 0.0
    ax.plot(t - t0, e * 100.0, color="tab:blue", lw=1.0, label="position [cm]")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [cm]")
    ax.grid(True, lw=0.3, alpha=0.5)
    if heading_errors is not None:
        h = np.asarray(heading_errors, dtype=np.float64)
        ax2 = ax.twinx()
        ax2.plot(t - t0, np.degrees(h), color="tab:orange", lw=0.8, label="heading [deg]")
        ax2.set_ylabel("heading error [deg]")
    if title:
        ax.set_title(title)
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig
