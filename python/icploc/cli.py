"""The ``icploc`` command line (typer)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(
    name="icploc",
    help="Real-time 2D robot localization by ICP against a known map.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _register() -> None:
    """Attach the sub-command groups that live beside the code they drive."""
    from icploc.maps.cli import map_app

    app.add_typer(map_app, name="map", help="Load, fit, inspect and prepare maps.")


config_app = typer.Typer(help="Localizer configuration (YAML).", no_args_is_help=True)
app.add_typer(config_app, name="config")


@config_app.command("defaults")
def config_defaults() -> None:
    """Print the default localizer configuration as YAML."""
    from icploc.config import default_yaml

    typer.echo(default_yaml(), nl=False)


@config_app.command("check")
def config_check(path: Annotated[Path, typer.Argument(help="YAML file to validate")]) -> None:
    """Validate a configuration file (unknown keys and bad values are errors)."""
    cfg = _load_config(path)
    typer.echo(cfg.to_yaml(), nl=False)


def _load_config(path: Path | None):  # type: ignore[no-untyped-def]
    from icploc.config import ConfigError, LocalizerConfig

    if path is None:
        return LocalizerConfig()
    try:
        return LocalizerConfig.from_yaml(path)
    except ConfigError as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(2) from None


def _pose_option(text: str | None):  # type: ignore[no-untyped-def]
    from icploc.replay import parse_pose

    if text is None:
        return None
    try:
        return parse_pose(text)
    except ValueError as e:
        raise typer.BadParameter(str(e)) from None


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", help="Output directory")] = Path("icploc-demo"),
    quick: Annotated[bool, typer.Option(help="Short paths (a few seconds)")] = False,
    people: Annotated[int, typer.Option(help="People walking in the lab")] = 3,
    seed: Annotated[int, typer.Option(help="Random seed")] = 0,
) -> None:
    """The paper's lab experiments (random walk, circles) with a simulated PowerBot and
    PLS on pseudo-terminals: writes plots and Tables 3-5 style results."""
    import time

    from icploc.demo import run_demo

    t0 = time.perf_counter()
    results = run_demo(out, quick=quick, people=people, seed=seed, log=typer.echo)
    for r in results:
        s = r.summary()
        typer.echo(
            f"{r.name:12s} {s['distance_m']:5.1f} m, {int(s['scans'])} scans: localization error "
            f"median {s['median_error_m'] * 1000:.1f} mm, p95 {s['p95_error_m'] * 1000:.1f} mm, "
            f"max {s['max_error_m'] * 1000:.1f} mm; end error odometry "
            f"{s['odometry_end_error_m'] * 1000:.0f} mm, localization {s['localized_end_error_m'] * 1000:.1f} mm"
        )
    typer.echo(f"wrote {out}/results.md and plots in {time.perf_counter() - t0:.1f} s")


@app.command()
def replay(
    log: Annotated[
        Path, typer.Argument(help="CARMEN log (.log/.gz), ROS 1/2 bag, or icploc raw recording")
    ],
    map_path: Annotated[
        Path, typer.Option("--map", help="Map file (ROS YAML, GeoJSON, DXF, .npz ...)")
    ],
    initial_pose: Annotated[
        str | None, typer.Option("--initial-pose", help="X,Y,THETA (m, m, rad)")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the trajectory (TUM)")] = None,
    truth: Annotated[
        Path | None, typer.Option("--truth", help="True trajectory (TUM): ATE/RPE")
    ] = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Draw the map and trajectories (PNG)")
    ] = None,
    config: Annotated[Path | None, typer.Option("--config", help="Localizer config (YAML)")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar")] = True,
    odometry: Annotated[
        str, typer.Option(help="auto | stream | scan: odometry recorded with each scan (CARMEN) or the stream")
    ] = "auto",
) -> None:
    """Localize a recorded log against a map, deterministically and as fast as possible."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from icploc.replay import replay as do_replay

    cfg = _load_config(config)
    pose = _pose_option(initial_pose)
    try:
        if progress:
            with Progress(
                TextColumn("[bold]replay"), BarColumn(), TextColumn("{task.completed}/{task.total} scans"),
                TimeRemainingColumn(), transient=True,
            ) as bar:  # fmt: skip
                task = bar.add_task("replay", total=None)

                def on_progress(done: int, total: int) -> None:
                    bar.update(task, completed=done, total=total)

                res = do_replay(log, map_path, config=cfg, initial_pose=pose, out=out, truth=truth,
                                plot=plot, on_progress=on_progress, odometry=odometry)  # fmt: skip
        else:
            res = do_replay(log, map_path, config=cfg, initial_pose=pose, out=out, truth=truth,
                            plot=plot, odometry=odometry)  # fmt: skip
    except (OSError, ValueError) as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(1) from None
    typer.echo(res.summary())
    for k, p in res.files.items():
        typer.echo(f"{k}: {p}")


@app.command("run")
def run_cmd(
    map_path: Annotated[Path | None, typer.Option("--map", help="Map file")] = None,
    laser: Annotated[str | None, typer.Option("--laser", help="Laser serial port (PLS)")] = None,
    base: Annotated[str | None, typer.Option("--base", help="Base serial port (PowerBot)")] = None,
    simulate: Annotated[
        bool, typer.Option("--simulate", help="Use the device simulators on ptys")
    ] = False,
    initial_pose: Annotated[str | None, typer.Option("--initial-pose", help="X,Y,THETA")] = None,
    global_start: Annotated[
        bool,
        typer.Option("--global", help="With --simulate: do not tell the localizer the start pose"),
    ] = False,
    out: Annotated[Path | None, typer.Option("--out", help="Write the trajectory (TUM)")] = None,
    record: Annotated[Path | None, typer.Option("--record", help="Record the raw bytes")] = None,
    config: Annotated[Path | None, typer.Option("--config", help="Localizer config (YAML)")] = None,
    duration: Annotated[float | None, typer.Option(help="Stop after this many seconds")] = None,
    baud: Annotated[int, typer.Option(help="Laser baud rate")] = 38400,
    reconnect_timeout: Annotated[
        float,
        typer.Option(help="Give up on a vanished device after this many seconds (exit 1)"),
    ] = 60.0,
) -> None:
    """Localize live from a PLS and a PowerBot (or their simulators with --simulate).

    The ports and the outputs are checked before anything is opened or written. A
    device that vanishes is reconnected automatically; meanwhile the estimate coasts on
    odometry (laser missing) or is matched without odometry (base missing), its status
    saying so. Ctrl-C ends the run with complete files and a summary.

    Exit codes: 0 done (also after Ctrl-C); 1 error (a port, a device that does not
    answer or does not come back, a file); 2 usage (missing options, an output that is an
    input); 130 Ctrl-C before the devices answered."""
    from icploc import live

    seconds = "must be a positive number of seconds"
    if duration is not None and not duration > 0:
        raise typer.BadParameter(seconds, param_hint="--duration")
    if not reconnect_timeout > 0:
        raise typer.BadParameter(seconds, param_hint="--reconnect-timeout")
    if baud not in (9600, 19200, 38400, 500000):
        raise typer.BadParameter("one of 9600, 19200, 38400, 500000 Bd", param_hint="--baud")
    if not simulate and (map_path is None or laser is None):
        raise typer.BadParameter("--map and --laser are required (or use --simulate)")
    cfg = _load_config(config)
    pose = _pose_option(initial_pose)

    def show(e):  # type: ignore[no-untyped-def]
        why = f" ({e.reason})" if e.reason and (e.status.value == "lost" and e.reason != "lost"
                                                or e.reason in live.MISSING_REASONS) else ""  # fmt: skip
        typer.echo(
            f"{e.stamp:.3f} x={e.x:+.3f} y={e.y:+.3f} th={e.theta:+.3f} {e.status}{why} inliers={e.inlier_ratio:.2f}"
        )

    try:
        if simulate:
            res, truth = live.run_simulated(config=cfg if config is not None else None, out=out, record=record,
                                            on_estimate=show, map_=str(map_path) if map_path else None,
                                            timeout=duration or 120.0, global_start=global_start,
                                            reconnect_timeout=reconnect_timeout, config_path=config)  # fmt: skip
        else:
            assert map_path is not None and laser is not None
            res = live.run_hardware(map_path, laser, base, config=cfg, config_path=config, initial_pose=pose,
                                    out=out, record=record, laser_baud=baud, duration=duration,
                                    reconnect_timeout=reconnect_timeout, on_estimate=show)  # fmt: skip
    except live.RunError as e:
        typer.secho(f"error: {e}", fg="red", err=True)
        raise typer.Exit(e.exit_code) from None
    except KeyboardInterrupt:
        typer.secho("interrupted before the devices answered; nothing written", fg="red", err=True)
        raise typer.Exit(130) from None
    typer.echo(res.summary())
    if simulate and res.estimates:
        import numpy as np

        T = live.truth_at(truth, [e.stamp for e in res.estimates])
        P = np.array([e.pose for e in res.estimates])
        err = np.hypot(*(P[:, :2] - T[:, :2]).T)
        typer.echo(
            f"{len(P)} estimates; error vs simulator truth: median {np.median(err) * 1000:.1f} mm, max {err.max() * 1000:.1f} mm"
        )
    for k, p in res.files.items():
        typer.echo(f"{k}: {p}")
    for w in res.write_errors:
        typer.secho(f"error: {w}", fg="red", err=True)
    if res.error is not None:
        typer.secho(f"error: {res.error}", fg="red", err=True)
    if res.error is not None or res.write_errors:
        raise typer.Exit(1)


def main() -> None:
    _register()
    app()


if __name__ == "__main__":
    main()
