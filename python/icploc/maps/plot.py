"""Pictures of a map: occupancy grid, wall lines, samples (and optionally a pose and what it sees)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from .map import Map


def plot_map(
    m: Map,
    ax: Axes | None = None,
    *,
    spacing: float | None = 0.1,
    grid: bool = True,
    lines: bool = True,
    normals: bool = False,
    pose: Sequence[float] | None = None,
    fov: float = 2 * math.pi,
    max_range: float = 30.0,
    title: str | None = None,
) -> Axes:
    """Draw ``m`` on ``ax`` (a new figure if None): the grid in grey (occupied black, unknown
    mid-grey), the lines in red, the samples at ``spacing`` as blue dots (``None``: no
    samples), with ``pose`` a green arrow and the samples it sees in orange."""
    import matplotlib.pyplot as plt
    from matplotlib.transforms import Affine2D

    if ax is None:
        _, ax = plt.subplots(figsize=(9, 9))
    if grid and m.grid is not None and m.resolution is not None:
        img = np.full(m.grid.shape, 0.75)
        if m.free is not None:
            img[m.free] = 1.0
        img[m.grid] = 0.0
        h, w = m.grid.shape
        res = m.resolution
        ox, oy, yaw = m.origin
        tr = Affine2D().rotate(yaw).translate(ox, oy) + ax.transData
        ax.imshow(
            img,
            cmap="gray",
            vmin=0,
            vmax=1,
            origin="lower",
            interpolation="nearest",
            extent=(0, w * res, 0, h * res),
            transform=tr,
            zorder=0,
        )
    if lines and len(m.lines):
        xs = np.column_stack([m.lines[:, 0], m.lines[:, 2], np.full(len(m.lines), np.nan)]).ravel()
        ys = np.column_stack([m.lines[:, 1], m.lines[:, 3], np.full(len(m.lines), np.nan)]).ravel()
        ax.plot(xs, ys, "-", color="tab:red", lw=1.0, label=f"{len(m.lines)} lines", zorder=4)
    if spacing is not None:
        p, n = m.sample(spacing)
        ax.plot(
            p[:, 0],
            p[:, 1],
            ".",
            color="tab:blue",
            ms=1.5,
            label=f"{len(p)} samples @ {spacing} m",
            zorder=3,
        )
        if normals and len(p):
            ax.quiver(p[:, 0], p[:, 1], n[:, 0], n[:, 1], color="tab:blue", width=0.002, zorder=3)
        if pose is not None:
            idx = m.visible(pose, fov=fov, max_range=max_range, spacing=spacing)
            ax.plot(
                p[idx, 0],
                p[idx, 1],
                ".",
                color="tab:orange",
                ms=3,
                label=f"{len(idx)} visible",
                zorder=5,
            )
    if pose is not None:
        L = 0.05 * max(1e-9, max(m.bounds[2] - m.bounds[0], m.bounds[3] - m.bounds[1]))
        ax.arrow(
            pose[0],
            pose[1],
            L * math.cos(pose[2]),
            L * math.sin(pose[2]),
            color="tab:green",
            width=L * 0.15,
            zorder=6,
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title if title is not None else (Path(m.source).name if m.source else "map"))
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize="small")
    return ax


def save_map_plot(m: Map, out: str | Path, *, dpi: int = 150, **options: Any) -> Path:
    """Render :func:`plot_map` to an image file (PNG, SVG, PDF by suffix) without a display."""
    # a figure on its own Agg canvas: no pyplot state, the caller's backend left alone
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 10))
    FigureCanvasAgg(fig)
    plot_map(m, ax=fig.add_subplot(1, 1, 1), **options)
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    return Path(out)
