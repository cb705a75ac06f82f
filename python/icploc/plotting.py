"""Pictures of a run: the map with the odometry, localized and true trajectories (like the
paper's Fig. 9–11), lost stretches marked, and the error over time. The one place that
draws a run: ``icploc replay --plot``, the demo and the benches use :func:`plot_run`.
matplotlib's Agg canvas, no pyplot state (nor ``matplotlib.use``), so it works headless
and from threads and leaves the caller's backend alone; matplotlib is imported only
when a figure is drawn.

Maps are plain arrays so this module does not depend on :mod:`icploc.maps`: ``lines``
(K, 4) as x0 y0 x1 y1, ``points`` (M, 2), or an occupancy ``grid`` image with its
``extent``. A map object with ``.lines`` (and optionally ``.points``) is accepted as ``map``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.trajectory import Trajectory

__all__ = ["ErrorSeries", "TrajLike", "plot_errors", "plot_run", "save_figure"]

TrajLike = Trajectory | ArrayLike  #: a Trajectory or an (N, 2+) array of x, y[, theta]

_STYLE: dict[str, dict[str, Any]] = {
    "truth": {"color": "0.45", "lw": 1.0, "ls": "--", "label": "truth", "zorder": 4},
    "odometry": {"color": "tab:red", "lw": 1.1, "ls": "--", "label": "odometry", "zorder": 2},
    "localized": {"color": "tab:blue", "lw": 1.8, "ls": "-", "label": "localization", "zorder": 3},
    "lost": {"color": "tab:orange", "lw": 1.4, "ls": ":", "zorder": 3},
    "glass": {"color": "tab:cyan", "lw": 3.0, "label": "glass", "zorder": 1},
    "people": {"color": "tab:orange", "lw": 0.6, "ls": ":", "alpha": 0.7, "zorder": 1},
}


class ErrorSeries(Protocol):
    """Errors over time, as :class:`icploc.trajectory.AteResult` holds them."""

    @property
    def stamps(self) -> NDArray[np.float64]: ...

    @property
    def position_errors(self) -> NDArray[np.float64]: ...

    @property
    def heading_errors(self) -> NDArray[np.float64]: ...


def _xy(t: TrajLike) -> NDArray[np.float64]:
    if isinstance(t, Trajectory):
        return t.sorted().xy
    a = np.asarray(t, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] < 2:
        raise ValueError(
            f"a trajectory must be a Trajectory or an (N, 2+) array, got shape {a.shape}"
        )
    return a[:, :2]


def _lost_mask(t: TrajLike, status: Sequence[Any], n: int) -> NDArray[np.bool_]:
    """Which rows of ``t`` (in drawing order) are ``lost``; ``status`` in ``t``'s order."""
    vals = [str(getattr(s, "value", s)) for s in status]
    if len(vals) != n:
        raise ValueError(f"status has {len(vals)} entries for a trajectory of {n} poses")
    lost = np.array([v == "lost" for v in vals], dtype=bool)
    if isinstance(t, Trajectory):
        lost = lost[np.argsort(t.stamps, kind="stable")]
    return lost


def _stretches(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``mask``."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1, strict=True))


def _figure(figsize: tuple[float, float]) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 150) -> None:
    """Save a figure (PNG, SVG or PDF by extension)."""
    fig.savefig(os.fspath(path), dpi=dpi, bbox_inches="tight")


def _segments(ax: Any, lines: ArrayLike, style: dict[str, Any]) -> None:
    from matplotlib.collections import LineCollection

    L = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    if len(L):
        st = dict(style)
        ax.add_collection(
            LineCollection(
                list(L.reshape(-1, 2, 2)),
                colors=st.pop("color"),
                linewidths=st.pop("lw"),
                **st,
            )
        )
        ax.update_datalim(L.reshape(-1, 2))


def _draw_errors(
    ax: Any,
    stamps: ArrayLike,
    position_errors: ArrayLike,
    heading_errors: ArrayLike | None,
    lost_times: Sequence[tuple[float, float]] = (),
) -> None:
    """Position error (cm) and heading error (deg, right axis) over time on ``ax``."""
    t = np.asarray(stamps, dtype=np.float64)
    e = np.asarray(position_errors, dtype=np.float64)
    if t.shape != e.shape:
        raise ValueError(f"stamps {t.shape} and errors {e.shape} differ in shape")
    t0 = float(t[0]) if len(t) else 0.0
    (h1,) = ax.plot(t - t0, e * 100.0, color="tab:blue", lw=1.0, label="position error")
    handles = [h1]
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [cm]")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.3, alpha=0.5)
    for k, (a, b) in enumerate(lost_times):
        span = ax.axvspan(a - t0, b - t0, color="tab:orange", alpha=0.2, lw=0,
                          label="lost" if k == 0 else None)  # fmt: skip
        if k == 0:
            handles.append(span)
    if heading_errors is not None:
        h = np.asarray(heading_errors, dtype=np.float64)
        if h.shape != t.shape:
            raise ValueError(f"stamps {t.shape} and heading errors {h.shape} differ in shape")
        ax2 = ax.twinx()
        (h2,) = ax2.plot(t - t0, np.degrees(h), color="tab:green", lw=0.8, label="heading error")
        ax2.set_ylabel("heading error [deg]")
        ax2.set_ylim(bottom=0.0)
        handles.append(h2)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.12, 1.0), fontsize=8,
              borderaxespad=0.0)  # fmt: skip


def plot_run(
    path: str | os.PathLike[str] | None = None,
    *,
    map: Any = None,  # noqa: A002 - the natural name here
    lines: ArrayLike | None = None,
    points: ArrayLike | None = None,
    grid: ArrayLike | None = None,
    extent: Sequence[float] | None = None,
    glass: ArrayLike | None = None,
    people: Sequence[ArrayLike] = (),
    truth: TrajLike | None = None,
    odometry: TrajLike | None = None,
    localized: TrajLike | None = None,
    status: Sequence[Any] | None = None,
    others: Mapping[str, TrajLike] | None = None,
    scan_points: ArrayLike | None = None,
    errors: ErrorSeries | None = None,
    title: str | None = None,
    figsize: tuple[float, float] | None = None,
    mark_ends: bool = True,
    dpi: int = 150,
) -> Any:
    """Draw the map and the trajectories; save to ``path`` if given; return the Figure.

    Axes in metres; the legend sits outside the map, right of it, so it hides no wall.
    ``grid``: an occupancy image (rows from the top, values 0 free … 1 or 100 occupied,
    negative unknown) drawn with ``extent`` = (xmin, xmax, ymin, ymax). ``glass``: (G, 4)
    glass segments; ``people``: the closed paths people walk (drawn dotted).
    ``status``: per pose of ``localized`` (``tracking`` / ``degraded`` / ``lost``, strings
    or enums): lost stretches are drawn dotted as the dead-reckoned guess they are, never
    as part of the localized line. ``errors``: position and heading errors over time
    (:class:`icploc.trajectory.AteResult`, e.g. against the truth): adds a panel below
    the map, lost stretches shaded. ``others``: extra named trajectories. ``scan_points``:
    (M, 2) world points of a scan to overlay. Start points are marked with a circle and
    end points with a square.
    """
    if map is not None:
        if lines is None and getattr(map, "lines", None) is not None:
            lines = map.lines
        if points is None and getattr(map, "points", None) is not None:
            points = map.points
    if figsize is None:
        figsize = (8.0, 9.5) if errors is not None else (8.0, 7.0)
    fig = _figure(figsize)
    if errors is not None:
        gs = fig.add_gridspec(2, 1, height_ratios=(3.2, 1.0))
        ax = fig.add_subplot(gs[0])
        eax = fig.add_subplot(gs[1])
    else:
        ax = fig.add_subplot(1, 1, 1)
        eax = None
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
        _segments(ax, lines, {"color": "k", "lw": 1.2, "label": "map"})
    if glass is not None:
        _segments(ax, glass, _STYLE["glass"])
    for k, walk in enumerate(people):
        w = np.asarray(walk, dtype=np.float64).reshape(-1, 2)
        loop = np.vstack([w, w[:1]])
        ax.plot(loop[:, 0], loop[:, 1], **_STYLE["people"],
                label="people walking" if k == 0 else None)  # fmt: skip
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
    lost_times: list[tuple[float, float]] = []
    for name, t, st in trajs:
        xy = _xy(t)
        if len(xy) == 0:
            continue
        if name == "localized" and status is not None:
            lost = _lost_mask(t, status, len(xy))
            ok_xy = xy.copy()
            ok_xy[lost] = np.nan
            ax.plot(ok_xy[:, 0], ok_xy[:, 1], **st)
            if lost.any():
                keep = lost.copy()
                keep[1:] |= lost[:-1]  # join each lost stretch to the pose before it
                lost_xy = xy.copy()
                lost_xy[~keep] = np.nan
                ax.plot(lost_xy[:, 0], lost_xy[:, 1], **_STYLE["lost"],
                        label=f"lost, dead-reckoned ({int(lost.sum())} poses)")  # fmt: skip
                if isinstance(t, Trajectory):
                    ts = t.sorted().stamps
                    lost_times = [(float(ts[a]), float(ts[b])) for a, b in _stretches(lost)]
        else:
            ax.plot(xy[:, 0], xy[:, 1], **st)
        if mark_ends:
            z = st.get("zorder", 2) + 0.5
            ax.plot(xy[0, 0], xy[0, 1], "o", color=st["color"], ms=6, mfc="none", zorder=z)
            ax.plot(xy[-1, 0], xy[-1, 1], "s", color=st["color"], ms=6, mfc="none", zorder=z)
    ax.set_aspect("equal", adjustable="box")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3, alpha=0.5)
    if title:
        ax.set_title(title)
    handles, labels = ax.get_legend_handles_labels()
    if mark_ends and trajs:
        from matplotlib.lines import Line2D

        handles += [
            Line2D([], [], marker="o", ls="", color="0.3", mfc="none"),
            Line2D([], [], marker="s", ls="", color="0.3", mfc="none"),
        ]
        labels += ["start", "end"]
    if handles:
        # outside the map: a legend inside would hide the walls of one corner
        ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8,
                  framealpha=0.9, borderaxespad=0.0)  # fmt: skip
    if eax is not None and errors is not None:
        _draw_errors(eax, errors.stamps, errors.position_errors, errors.heading_errors, lost_times)
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
    """Position error (cm) and, if given, heading error (deg) over time, alone (the panel
    :func:`plot_run` draws under the map when given ``errors``)."""
    fig = _figure(figsize)
    ax = fig.add_subplot(1, 1, 1)
    _draw_errors(ax, stamps, position_errors, heading_errors)
    if title:
        ax.set_title(title)
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig
