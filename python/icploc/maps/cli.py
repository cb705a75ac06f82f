"""``icploc map ...``: inspect, draw, prepare and convert maps."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import typer

from .errors import MapError

map_app = typer.Typer(no_args_is_help=True, help="Load, fit, inspect and prepare maps.")


#: help of the ``--no-cache`` option of every command that loads a map
NO_CACHE_HELP = "fit the map afresh: neither read nor write the cache of prepared maps"


def load_map(path: Path, *, no_cache: bool = False, **options: object):  # type: ignore[no-untyped-def]
    """``Map.load`` for CLI commands: ``no_cache`` is the ``--no-cache`` flag."""
    from .map import Map

    return Map.load(path, cache=False if no_cache else None, **options)


#: exit code of a map that cannot be read or written (icploc's "error", see ``icploc --help``)
EXIT_ERROR = 1


def _fail(e: Exception) -> typer.Exit:
    typer.echo(f"error: {e}", err=True)
    return typer.Exit(EXIT_ERROR)


def _check_out(out: Path, inputs: list[Path]) -> None:
    """Refuse, before any work, an output (and the image a .yaml output writes beside it)
    that is an input or cannot be written."""
    from icploc.outputs import OutputError, check_outputs

    outs: dict[str, Path] = {"--out": out}
    if out.suffix.lower() in (".yaml", ".yml"):
        outs["--out image"] = out.with_suffix(".pgm")
    try:
        check_outputs(outs, inputs)
    except OutputError as e:
        raise _fail(e) from e


def _map_inputs(path: Path) -> list[Path]:
    from icploc.outputs import map_inputs

    return map_inputs(path)


def _load(path: Path, min_length: float | None = None, no_cache: bool = False):  # type: ignore[no-untyped-def]
    opts = {} if min_length is None else {"min_length": min_length}
    try:
        return load_map(path, no_cache=no_cache, **opts)
    except MapError as e:
        raise _fail(e) from e


@map_app.command()
def show(
    map_path: Path = typer.Argument(..., help="map file (.yaml, .geojson, .dxf, .npy, .csv, .npz)"),
    out: Path = typer.Option(
        Path("map.png"), "--out", "-o", help="image to write (.png, .svg, .pdf)"
    ),
    spacing: float = typer.Option(0.1, help="sample spacing to draw; 0 draws no samples (m)"),
    pose: str | None = typer.Option(
        None, help="'x,y,theta' to draw a scanner and what it sees (m, m, rad)"
    ),  # noqa: UP007
    fov: float = typer.Option(360.0, help="field of view with --pose (deg)"),
    max_range: float = typer.Option(30.0, help="max range with --pose (m)"),
    normals: bool = typer.Option(False, help="draw sample normals"),
    dpi: int = typer.Option(150, help="image resolution (dots per inch)"),
    no_cache: bool = typer.Option(False, "--no-cache", help=NO_CACHE_HELP),
) -> None:
    """Draw the grid, the fitted lines and the samples to an image."""
    from .plot import save_map_plot

    _check_out(out, _map_inputs(map_path))
    m = _load(map_path, no_cache=no_cache)
    p = None
    if pose:
        try:
            p = tuple(float(v) for v in pose.split(","))
            assert len(p) == 3
        except (ValueError, AssertionError) as e:
            raise typer.BadParameter("--pose must be 'x,y,theta'") from e
    save_map_plot(
        m,
        out,
        spacing=spacing if spacing > 0 else None,
        pose=p,
        fov=math.radians(fov),
        max_range=max_range,
        normals=normals,
        dpi=dpi,
    )
    typer.echo(f"wrote {out}")


@map_app.command()
def info(
    map_path: Path = typer.Argument(..., help="map file"),
    spacing: float = typer.Option(0.05, help="sample spacing for the point counts (m)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON"),
    no_cache: bool = typer.Option(False, "--no-cache", help=NO_CACHE_HELP),
) -> None:
    """Print what the map holds: format, lines, fit quality, sample counts and timings."""
    t0 = time.perf_counter()
    m = _load(map_path, no_cache=no_cache)
    t1 = time.perf_counter()
    d = m.info()
    d["samples"] = m.sample_counts(spacing)
    t2 = time.perf_counter()
    d["spacing"] = spacing
    d["timing_s"] = {"load_and_fit": round(t1 - t0, 4), "sample": round(t2 - t1, 4)}
    if as_json:
        typer.echo(json.dumps(d, indent=1, default=str))
        return
    for k, v in d.items():
        typer.echo(f"{k:>16}: {v}")


@map_app.command()
def prepare(
    map_path: Path = typer.Argument(..., help="map file"),
    out: Path = typer.Option(..., "--out", "-o", help="prepared map to write (.npz)"),
    spacing: list[float] = typer.Option([0.05], help="sample spacing(s) to store (m)"),
    min_length: float | None = typer.Option(None, help="shortest fitted line for grids (m)"),  # noqa: UP007
    no_cache: bool = typer.Option(False, "--no-cache", help=NO_CACHE_HELP),
) -> None:
    """Fit and sample once; save everything to one .npz that loads fast."""
    _check_out(out, _map_inputs(map_path))
    m = _load(map_path, min_length, no_cache=no_cache)
    try:
        m.save(out, spacing=spacing)
    except MapError as e:
        raise _fail(e) from e
    counts = {s: m.sample_counts(s)["total"] for s in spacing}
    typer.echo(f"wrote {out}: {len(m.lines)} lines, samples {counts}")


@map_app.command()
def convert(
    map_path: Path = typer.Argument(..., help="map file"),
    out: Path = typer.Option(
        ..., "--out", "-o", help=".geojson (lines), .yaml (ROS grid) or .npz (prepared map)"
    ),
    resolution: float = typer.Option(0.05, help="cell size for .yaml output (m)"),
    no_cache: bool = typer.Option(False, "--no-cache", help=NO_CACHE_HELP),
) -> None:
    """Write the map in the format of the --out suffix (icploc.maps.formats): its lines as
    GeoJSON, rasterised into a ROS map_server map, or prepared (.npz)."""
    from .formats import format_for

    try:
        fmt = format_for(out, writing=True)
    except MapError as e:
        raise typer.BadParameter(e.reason, param_hint="--out") from None
    _check_out(out, _map_inputs(map_path))
    m = _load(map_path, no_cache=no_cache)
    try:
        assert fmt.save is not None
        fmt.save(m, out, {"resolution": resolution})
    except MapError as e:
        raise _fail(e) from e
    typer.echo(f"wrote {out}")


@map_app.command()
def build(
    log: Path = typer.Argument(..., help="log file (CARMEN, ROS bag, icploc recording)"),
    out: Path = typer.Option(..., "--out", "-o", help="map_server YAML to write (.yaml)"),
    poses: Path | None = typer.Option(  # noqa: UP007
        None, help="TUM file of laser poses (default: the log's own corrected poses)"
    ),
    resolution: float = typer.Option(0.05, help="cell size (m)"),
    min_hits: int = typer.Option(2, help="beam hits a cell needs to be occupied (count)"),
    max_range: float = typer.Option(30.0, help="use beams up to this range (m)"),
) -> None:
    """Build a map_server map (YAML + PGM) from a log's scans at known poses; free space by
    ray casting."""
    from .build import build_grid

    if out.suffix.lower() not in (".yaml", ".yml"):
        raise typer.BadParameter("--out must end in .yaml")
    _check_out(out, [log] + ([poses] if poses is not None else []))
    try:
        t0 = time.perf_counter()
        g = build_grid(
            log, poses=poses, resolution=resolution, min_hits=min_hits, max_range=max_range
        )
        g.save(out)
    except (MapError, OSError, ValueError) as e:
        raise _fail(e) from e
    h, w = g.occupied.shape
    typer.echo(
        f"wrote {out}: {w} x {h} cells at {resolution} m from {g.scans_used} scans, "
        f"{int(g.occupied.sum())} occupied, {int(g.free.sum())} free "
        f"({time.perf_counter() - t0:.1f} s)"
    )


@map_app.command()
def merge(
    map_path: Path = typer.Argument(..., help="map_server map (.yaml) to extend"),
    patch: Path = typer.Argument(..., help="map patch (.yaml; icploc replay --map-patch)"),
    out: Path = typer.Option(..., "--out", "-o", help="merged map_server map to write (.yaml)"),
) -> None:
    """Merge a map patch into a map: cells the map knows keep its value, cells it does not
    know (unknown, beyond its edge) take the patch's."""
    from icploc.outputs import OutputError

    from .merge import merge_files

    try:
        r = merge_files(map_path, patch, out)
    except (MapError, OutputError, OSError) as e:
        raise _fail(e) from e
    h, w = r.occupied.shape
    shift = f"; patch moved {r.shift * 100:.1f} cm onto the map's cells" if r.shift > 1e-6 else ""
    typer.echo(
        f"wrote {out}: {w} x {h} cells at {r.resolution} m; the patch added "
        f"{r.added_occupied} occupied and {r.added_free} free cells{shift}"
    )
