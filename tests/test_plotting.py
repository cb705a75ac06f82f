"""Plot helpers: PNGs are written, and what they draw is the data given."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from icploc.plotting import plot_errors, plot_run
from icploc.trajectory import Trajectory

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _square_map() -> np.ndarray:
    return np.array(
        [[0, 0, 7.5, 0], [7.5, 0, 7.5, 7.5], [7.5, 7.5, 0, 7.5], [0, 7.5, 0, 0]], dtype=float
    )


def _traj(offset: float = 0.0) -> Trajectory:
    t = np.arange(50) * 0.1
    a = np.linspace(0, 2 * np.pi, 50)
    return Trajectory.from_poses(
        t, np.column_stack((3.75 + 2 * np.cos(a) + offset, 3.75 + 2 * np.sin(a), a))
    )


def test_plot_run_writes_png_with_all_layers(tmp_path: Path) -> None:
    out = tmp_path / "run.png"
    fig = plot_run(
        out,
        lines=_square_map(),
        points=np.array([[1.0, 1.0], [2.0, 2.0]]),
        truth=_traj(),
        odometry=_traj(0.3),
        localized=_traj(0.01).poses,  # plain arrays work too
        others={"raw icp": _traj(-0.2)},
        scan_points=np.array([[3.0, 3.0]]),
        title="lab",
    )
    data = out.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5000
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    for want in ("truth", "odometry", "localization", "raw icp", "scan"):
        assert want in labels
    assert ax.get_title() == "lab"
    odo = next(line for line in ax.get_lines() if line.get_label() == "odometry")
    assert np.allclose(odo.get_xydata(), _traj(0.3).xy)
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    assert x0 <= 0.0 and x1 >= 7.5 and y0 <= 0.0 and y1 >= 7.5  # the whole map is in view


def test_plot_run_pixels_show_the_map(tmp_path: Path) -> None:
    import matplotlib.image as mpimg

    out = tmp_path / "walls.png"
    plot_run(out, lines=_square_map(), figsize=(4, 4), dpi=50)
    img = mpimg.imread(str(out))
    gray = img[..., :3].mean(axis=2)
    assert (gray < 0.2).sum() > 200  # black wall pixels
    assert (gray > 0.9).mean() > 0.5  # mostly white paper


def test_plot_run_accepts_map_objects_and_grids(tmp_path: Path) -> None:
    m = SimpleNamespace(lines=_square_map(), points=None)
    fig = plot_run(tmp_path / "m.png", map=m, localized=_traj())
    assert len(fig.axes[0].collections) == 1  # the LineCollection of the map
    grid = np.zeros((20, 30))
    grid[0, :] = 100
    grid[5:8, 5:8] = -1
    fig2 = plot_run(tmp_path / "g.png", grid=grid, extent=(0, 3, 0, 2), truth=_traj())
    assert len(fig2.axes[0].images) == 1
    assert (tmp_path / "g.png").read_bytes().startswith(PNG_MAGIC)


def test_plot_run_without_path_returns_figure_only(tmp_path: Path) -> None:
    fig = plot_run(None, truth=_traj())
    assert fig.axes and not list(tmp_path.iterdir())


def test_plot_run_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match=r"\(N, 2\+\)"):
        plot_run(None, truth=np.zeros(5))
    with pytest.raises(ValueError, match="2-D image"):
        plot_run(None, grid=np.zeros(5))


def test_plot_errors(tmp_path: Path) -> None:
    t = np.arange(100) * 0.1 + 50.0
    e = np.abs(np.sin(t)) * 0.01
    fig = plot_errors(tmp_path / "e.png", t, e, e * 0.1, title="err")
    assert (tmp_path / "e.png").read_bytes().startswith(PNG_MAGIC)
    line = fig.axes[0].get_lines()[0]
    assert np.allclose(line.get_ydata(), e * 100.0)
    assert line.get_xdata()[0] == 0.0
    with pytest.raises(ValueError, match="shape"):
        plot_errors(None, t, e[:-1])


def _lost_run() -> tuple[Trajectory, list[str]]:
    tr = _traj()
    status = ["tracking"] * 20 + ["lost"] * 10 + ["degraded"] * 20
    return tr, status


def test_lost_stretch_is_dotted_and_not_part_of_the_localized_line() -> None:
    tr, status = _lost_run()
    ax = plot_run(None, localized=tr, status=status).axes[0]
    loc = next(line for line in ax.get_lines() if line.get_label() == "localization")
    lost = next(line for line in ax.get_lines() if line.get_label().startswith("lost"))
    got = (
        int(np.isnan(loc.get_xydata()[:, 0]).sum()),
        int(np.isfinite(lost.get_xydata()[:, 0]).sum()),  # the 10 lost + the pose before
        lost.get_linestyle(),
    )
    assert got == (10, 11, ":")


def test_status_must_match_the_trajectory() -> None:
    tr, status = _lost_run()
    with pytest.raises(ValueError, match="status has 49 entries"):
        plot_run(None, localized=tr, status=status[:-1])


def test_error_panel_under_the_map_shades_lost_time() -> None:
    from icploc.trajectory import ate

    tr, status = _lost_run()
    errors = ate(Trajectory(tr.stamps, tr.poses + [0.01, 0.0, 0.0]), tr)
    fig = plot_run(None, lines=_square_map(), truth=tr, localized=tr, status=status, errors=errors)
    eax = fig.axes[1]
    shaded = [p for p in eax.patches if p.get_label() == "lost"]
    got = (eax.get_xlabel(), np.allclose(eax.get_lines()[0].get_ydata(), 1.0), len(shaded))
    assert got == ("time [s]", True, 1)


def test_legend_sits_outside_the_map(tmp_path: Path) -> None:
    """The legend must not hide a wall: it is drawn right of the map axes."""
    fig = plot_run(tmp_path / "l.png", lines=_square_map(), truth=_traj(), localized=_traj())
    ax = fig.axes[0]
    fig.canvas.draw()
    leg = ax.get_legend().get_window_extent()
    assert leg.x0 >= ax.get_window_extent().x1


def test_glass_and_people_are_drawn_and_named() -> None:
    glass = np.array([[2.0, 7.5, 5.5, 7.5]])
    walk = np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 2.0]])
    ax = plot_run(None, lines=_square_map(), glass=glass, people=[walk, walk + 1]).axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert (labels.count("glass"), labels.count("people walking")) == (1, 1)
