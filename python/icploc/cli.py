"""The ``icploc`` command line: the commands, declared once (:mod:`icploc.cli_args`).

``icploc replay LOG --map MAP ...`` and the other commands of this module run without
typer when their command line is plain (:func:`icploc.cli_args.parse_plain`): the command
then starts in milliseconds. Help, usage errors, the sub-apps (``map``, ``sim``) and the
tests go through the typer app, ``icploc.cli.app`` (:mod:`icploc.cli_app`), built from the
same declarations on first use."""

from __future__ import annotations

import gc
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from icploc.batch_cli import batch as _batch_command
from icploc.cli_args import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_LOST,
    EXIT_OK,
    EXIT_USAGE,
    Annotated,
    Argument,
    BadUsage,
    CommandExit,
    Commands,
    Option,
    describe,
    echo,
    parse_plain,
    run_guarded,
    secho,
)
from icploc.errors import UsageError

if TYPE_CHECKING:
    import typer

__all__ = ["COMMANDS", "EXIT_ERROR", "EXIT_INTERRUPTED", "EXIT_LOST", "EXIT_OK", "EXIT_USAGE", "main"]

HELP = """Real-time 2D robot localization by ICP against a known map.

\b
Exit codes:
  0    done
  1    error (missing or malformed file, bad value in it, write error)
  2    usage error (unknown option, bad option value, bad config file)
  3    replay finished but lost more than --max-lost of its scans
  130  interrupted by Ctrl-C (the summary is printed, the files are complete)
"""


class UserError(UsageError):
    """An error the user can fix: printed as one ``error: ...`` line (exit 1), no traceback."""


#: every command of this module (and ``icploc batch``), in the order ``icploc --help`` lists them
COMMANDS = Commands()
COMMANDS.group("config", "Localizer configuration (YAML).")
COMMANDS.group("log", "Inspect logs (CARMEN, ROS 1/2 bags, icploc recordings).")
COMMANDS.command("batch")(_batch_command)  # icploc batch (fleet): icploc.batch_cli

_REGISTERED: list[bool] = []


def __getattr__(name: str) -> Any:
    """``app``: the typer app of :data:`COMMANDS` (:mod:`icploc.cli_app`), built on first use."""
    if name != "app":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from icploc.cli_app import build

    got = globals()["app"] = build(COMMANDS, HELP)
    return got


def _app() -> typer.Typer:
    return __getattr__("app") if "app" not in globals() else globals()["app"]


def _register() -> None:
    """Attach the sub-command groups that live beside the code they drive (once)."""
    if _REGISTERED:
        return
    from icploc.cli_app import Guarded
    from icploc.maps.cli import map_app
    from icploc.sim.cli import sim_app

    app = _app()
    app.add_typer(map_app, name="map", help="Load, fit, inspect and prepare maps.", cls=Guarded)
    app.add_typer(sim_app, name="sim", help="Device simulators (PLS, PowerBot) on pseudo-terminals.", cls=Guarded)
    _REGISTERED.append(True)


@COMMANDS.command("defaults", group="config")
def config_defaults() -> None:
    """Print the default localizer configuration as YAML."""
    from icploc.config import default_yaml

    echo(default_yaml(), nl=False)


@COMMANDS.command("check", group="config")
def config_check(path: Annotated[Path, Argument(help="YAML file to validate")]) -> None:
    """Validate a configuration file exactly as replay and run do (unknown or duplicated
    keys and bad values are errors, exit 2); print the full configuration it gives."""
    cfg = _load_config(path)
    echo(cfg.to_yaml(), nl=False)


@COMMANDS.command("info", group="log")
def log_info(
    logs: Annotated[
        list[Path], Argument(help="CARMEN log (.log/.gz), ROS 1/2 bag, or icploc raw recording")
    ],
    format: Annotated[
        str | None,
        Option("--format", help="Read as this format (carmen, rosbag, recorded); default: detect"),
    ] = None,
    strict: Annotated[
        bool, Option("--strict", help="Refuse a malformed line or an impossible reading")
    ] = False,
) -> None:
    """Print what each log holds: scans, beams, odometry, time span, stamps, and what the
    reader skipped or repaired. A log that cannot be read is one error line (exit 1); the
    other logs are still read."""
    from icploc.logs import load_log

    failed = False
    for path in logs:
        try:
            opts = {"strict": True} if strict else {}
            echo(load_log(path, format=format, **opts).info.summary())
        except (ValueError, OSError) as e:
            secho(f"error: {describe(e)}", fg="red", err=True)
            failed = True
    if failed:
        raise CommandExit(EXIT_ERROR)


def _load_config(path: Path | None):  # type: ignore[no-untyped-def]
    from icploc.config import ConfigError, LocalizerConfig

    if path is None:
        return LocalizerConfig()
    try:
        return LocalizerConfig.from_yaml(path)
    except ConfigError as e:
        secho(f"error: {e}", fg="red", err=True)
        raise CommandExit(EXIT_USAGE) from None


def _pose_option(text: str | None):  # type: ignore[no-untyped-def]
    from icploc.replay import parse_pose

    if text is None:
        return None
    try:
        return parse_pose(text)
    except ValueError as e:
        raise BadUsage(str(e)) from None


@COMMANDS.command()
def demo(
    out: Annotated[Path, Option("--out", help="Output directory")] = Path("icploc-demo"),
    quick: Annotated[bool, Option(help="Short paths (a few seconds)")] = False,
    people: Annotated[int, Option(help="People walking in the lab (count)")] = 3,
    seed: Annotated[int, Option(help="Random seed (an integer)")] = 0,
) -> None:
    """The paper's lab experiments (random walk, circles) with a simulated PowerBot and
    PLS on pseudo-terminals: writes plots and Tables 3-5 style results."""
    import os
    import time

    from icploc.demo import run_demo

    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    base = out.absolute()
    while not base.exists():  # the demo makes the missing directories
        base = base.parent
    if not base.is_dir() or not os.access(base, os.W_OK | os.X_OK):
        raise UserError(f"--out {out}: cannot create a directory in {base}")
    t0 = time.perf_counter()
    results = run_demo(out, quick=quick, people=people, seed=seed, log=echo)
    for r in results:
        s = r.summary()
        echo(
            f"{r.name:12s} {s['distance_m']:5.1f} m, {int(s['scans'])} scans: localization error "
            f"median {s['median_error_m'] * 1000:.1f} mm, p95 {s['p95_error_m'] * 1000:.1f} mm, "
            f"max {s['max_error_m'] * 1000:.1f} mm; end error odometry "
            f"{s['odometry_end_error_m'] * 1000:.0f} mm, localization {s['localized_end_error_m'] * 1000:.1f} mm"
        )
    echo(f"wrote {out}/results.md and plots in {time.perf_counter() - t0:.1f} s")


# the options replay and run share (declared once)
InitialPoseOption = Annotated[str | None, Option("--initial-pose", help="X,Y,THETA (m, m, rad)")]
ConfigOption = Annotated[Path | None, Option("--config", help="Localizer config (YAML)")]
McapOption = Annotated[Path | None, Option("--mcap", help="Write a Foxglove MCAP of the run")]
RefineStartOption = Annotated[
    bool,
    Option(
        "--refine-start",
        help="Refine the initial pose from the first scans while the robot stands still; "
        "prints the verdict (refined / ambiguous / rejected / moved)",
    ),
]


@COMMANDS.command()
def replay(
    log: Annotated[
        Path, Argument(help="CARMEN log (.log/.gz), ROS 1/2 bag, or icploc raw recording")
    ],
    map_path: Annotated[
        Path, Option("--map", help="Map file (ROS YAML, GeoJSON, DXF, .npz ...)")
    ],
    initial_pose: InitialPoseOption = None,
    out: Annotated[
        Path | None, Option("--out", help="Write the trajectory (TUM), row by row")
    ] = None,
    estimates: Annotated[
        Path | None,
        Option(
            "--estimates",
            help="Write one CSV row per scan as it goes: stamp,x,y,theta,status,reason,"
            "inlier_ratio,cov_xx,cov_xy,cov_yy,cov_tt,...",
        ),
    ] = None,
    truth: Annotated[
        Path | None, Option("--truth", help="True trajectory (TUM): ATE/RPE")
    ] = None,
    plot: Annotated[
        Path | None, Option("--plot", help="Draw the map and trajectories (PNG)")
    ] = None,
    config: ConfigOption = None,
    progress: Annotated[bool, Option(help="Show a progress bar")] = True,
    odometry: Annotated[
        str, Option(help="auto | stream | scan: odometry recorded with each scan (CARMEN) or the stream")
    ] = "auto",
    strict: Annotated[
        bool,
        Option(
            "--strict",
            help="Refuse a log with a malformed line or an impossible reading (default: skip "
            "and count them, and say so in the summary)",
        ),
    ] = False,
    max_lost: Annotated[
        float,
        Option(
            "--max-lost",
            min=0.0,
            max=1.0,
            help="Exit 3 when more than this share of the scans ends lost; 1 = never (0-1)",
        ),
    ] = 0.5,
    mcap: McapOption = None,
    no_cache: Annotated[
        bool, Option("--no-cache", help="Fit the map afresh: neither read nor write the cache of prepared maps")
    ] = False,
    refine_start: RefineStartOption = False,
    partial_map: Annotated[
        bool | None, Option("--partial-map/--no-partial-map", help="Where the scan is outside the map, coast on odometry (reason outside_map, mapped 0, never tracking). On by default on map_server grids with at least one unknown cell (config outside.enabled; line and point maps: --partial-map); --no-partial-map turns it off, --partial-map turns it on over a config that disables it")
    ] = None,
    map_patch: Annotated[
        Path | None, Option("--map-patch", help="Write what the laser saw outside the map as a map_server grid (YAML + PGM; needs the outside-the-map state, on by default); merge it with 'icploc map merge'")
    ] = None,
    map_patch_open: Annotated[
        bool, Option("--map-patch-open", help="With --map-patch: also draw the stretches the run never brought back into the map (their poses are unchecked dead reckoning)")
    ] = False,
    confident_only: Annotated[
        bool, Option("--confident-only", help="In the --map-patch, leave unknown the wall cells whose walls are less sure than 5 cm (sigma from the pose graph), so a merged map keeps what it knew there")
    ] = False,
) -> None:
    """Localize a recorded log against a map, deterministically and as fast as possible.

    Malformed log lines are skipped and impossible readings ignored, each counted in the
    summary (--strict refuses them). The TUM and CSV files are written as the replay goes;
    Ctrl-C stops it with the summary and complete files. An output that is an input (the
    log, the map or its image, the truth, the config) or cannot be written is refused
    before any work starts."""
    from icploc.replay import replay as do_replay

    if odometry not in ("auto", "stream", "scan"):
        raise BadUsage(f"expected auto, stream or scan, got {odometry!r}", param_hint="--odometry")
    if confident_only and map_patch is None:
        raise BadUsage("needs --map-patch", param_hint="--confident-only")
    if map_patch_open and map_patch is None:
        raise BadUsage("needs --map-patch", param_hint="--map-patch-open")
    if partial_map is False and map_patch is not None:
        raise BadUsage("the map patch needs the outside-the-map state", param_hint="--no-partial-map")
    cfg = _load_config(config)
    pose = _pose_option(initial_pose)
    kw: dict[str, Any] = dict(
        config=cfg, initial_pose=pose, out=out, truth=truth, plot=plot, odometry=odometry,
        estimates=estimates, strict=strict, inputs=[config] if config is not None else [],
        map_cache=False if no_cache else None, partial_map=partial_map, map_patch=map_patch,
        map_patch_open=map_patch_open, map_patch_confident_only=confident_only,
    )  # fmt: skip
    hooks = _run_hooks(mcap=mcap, inputs=(log, map_path), refine_start=refine_start,
                       tell=echo)  # --mcap, --refine-start (icploc.hooks)  # fmt: skip
    kw["on_localizer"] = hooks.on_localizer
    try:
        if progress and sys.stdout.isatty():
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            with Progress(
                TextColumn("[bold]replay"), BarColumn(), TextColumn("{task.completed}/{task.total} scans"),
                TimeRemainingColumn(), transient=True,
            ) as bar:  # fmt: skip
                task = bar.add_task("replay", total=None)

                def on_progress(done: int, total: int) -> None:
                    bar.update(task, completed=done, total=total)

                res = do_replay(log, map_path, on_progress=on_progress, **kw)
        else:
            res = do_replay(log, map_path, **kw)
    finally:
        hooks.close()
    if mcap is not None:
        res.files["mcap"] = mcap
    echo(res.summary())
    for k, p in res.files.items():
        echo(f"{k}: {p}")
    if res.interrupted:
        raise CommandExit(EXIT_INTERRUPTED)
    if res.lost_share > max_lost:
        secho(
            f"error: {res.status_counts.get('lost', 0)} of {res.scans} scans "
            f"({res.lost_share:.0%}) ended lost, more than --max-lost {max_lost:g}",
            fg="red",
            err=True,
        )
        raise CommandExit(EXIT_LOST)


@COMMANDS.command("run")
def run_cmd(
    map_path: Annotated[Path | None, Option("--map", help="Map file")] = None,
    laser: Annotated[
        list[str] | None,
        Option("--laser", help="Laser serial port (PLS); repeat it for several lasers (scan.lasers)"),
    ] = None,
    base: Annotated[str | None, Option("--base", help="Base serial port (PowerBot)")] = None,
    simulate: Annotated[
        bool, Option("--simulate", help="Use the device simulators on ptys")
    ] = False,
    initial_pose: InitialPoseOption = None,
    global_start: Annotated[
        bool,
        Option("--global", help="With --simulate: do not tell the localizer the start pose"),
    ] = False,
    out: Annotated[Path | None, Option("--out", help="Write the trajectory (TUM)")] = None,
    record: Annotated[Path | None, Option("--record", help="Record the raw bytes")] = None,
    config: ConfigOption = None,
    duration: Annotated[float | None, Option(help="Stop after this long (s)")] = None,
    baud: Annotated[
        int, Option(help="Laser baud rate: 9600, 19200, 38400 or 500000 (Bd)")
    ] = 38400,
    mcap: McapOption = None,
    state: Annotated[
        Path | None, Option("--state", help="Restore the last pose from / save it to this file")
    ] = None,
    reconnect_timeout: Annotated[
        float,
        Option(help="Give up on a vanished device after this long, exit 1 (s)"),
    ] = 60.0,
    refine_start: RefineStartOption = False,
) -> None:
    """Localize live from a PLS and a PowerBot (or their simulators with --simulate).

    The ports and the outputs are checked before anything is opened or written. A
    device that vanishes is reconnected automatically; meanwhile the estimate coasts on
    odometry (laser missing) or is matched without odometry (base missing), its status
    saying so. Ctrl-C ends the run with complete files and a summary.

    With --simulate the simulated robot drives the built-in lab; --initial-pose is the
    pose the localizer is told (default: where the simulated robot starts), --global tells
    it nothing. The error against the simulator's truth counts the tracking estimates only.

    Exit codes: 0 done (also after Ctrl-C); 1 error (a port, a device that does not
    answer or does not come back, a file); 2 usage (missing options, an output that is an
    input); 130 Ctrl-C before the devices answered."""
    from icploc import live

    seconds = "must be a positive number of seconds"
    if duration is not None and not duration > 0:
        raise BadUsage(seconds, param_hint="--duration")
    if not reconnect_timeout > 0:
        raise BadUsage(seconds, param_hint="--reconnect-timeout")
    if baud not in (9600, 19200, 38400, 500000):
        raise BadUsage("one of 9600, 19200, 38400, 500000 Bd", param_hint="--baud")
    if not simulate and (map_path is None or not laser):
        raise BadUsage("--map and --laser are required (or use --simulate)")
    cfg = _load_config(config)
    pose = _pose_option(initial_pose)
    if global_start and pose is not None:
        raise BadUsage("--global and --initial-pose contradict each other: give one", param_hint="--global")
    # --mcap / --state (icploc.hooks): an explicit --initial-pose wins over a saved state
    hooks = _run_hooks(mcap=mcap, state=state, restore=pose is None, inputs=(map_path,) if map_path else (),
                       refine_start=refine_start, tell=echo)  # fmt: skip

    def show(e):  # type: ignore[no-untyped-def]
        hooks.observe(e)
        why = f" ({e.reason})" if e.reason and (e.status.value == "lost" and e.reason != "lost"
                                                or e.reason in live.MISSING_REASONS) else ""  # fmt: skip
        echo(
            f"{e.stamp:.3f} x={e.x:+.3f} y={e.y:+.3f} th={e.theta:+.3f} {e.status}{why} inliers={e.inlier_ratio:.2f}"
        )

    try:
        if simulate:
            from icploc.sim.harness import run_simulated

            res, truth = run_simulated(config=cfg if config is not None else None, out=out, record=record,
                                       on_estimate=show, map_=str(map_path) if map_path else None,
                                       initial_pose=pose, timeout=duration or 120.0, global_start=global_start,
                                       reconnect_timeout=reconnect_timeout, config_path=config,
                                       on_localizer=hooks.on_localizer)  # fmt: skip
        else:
            assert map_path is not None and laser
            res = live.run_hardware(map_path, laser[0], base, config=cfg, config_path=config, initial_pose=pose,
                                    out=out, record=record, laser_baud=baud, duration=duration,
                                    reconnect_timeout=reconnect_timeout, on_estimate=show,
                                    on_localizer=hooks.on_localizer, extra_lasers=laser[1:])  # fmt: skip
    except live.RunError as e:
        secho(f"error: {e}", fg="red", err=True)
        raise CommandExit(e.exit_code) from None
    except KeyboardInterrupt:
        secho("interrupted before the devices answered; nothing written", fg="red", err=True)
        raise CommandExit(130) from None
    finally:
        hooks.close()
    echo(res.summary())
    if simulate:
        _simulated_error(res.estimates, truth, map_path)
    for k, p in res.files.items():
        echo(f"{k}: {p}")
    for w in res.write_errors:
        secho(f"error: {w}", fg="red", err=True)
    if res.error is not None:
        secho(f"error: {res.error}", fg="red", err=True)
    if res.error is not None or res.write_errors:
        raise CommandExit(1)


def _simulated_error(estimates: list[Any], truth: list[Any], map_path: Path | None) -> None:
    """``run --simulate``: the error against the simulator's truth, over the estimates
    that claim to be right (tracking) only; a lost or degraded guess is no measurement."""
    import numpy as np

    from icploc.sim.harness import truth_at

    tracked = [e for e in estimates if e.status.value == "tracking"]
    others = len(estimates) - len(tracked)
    if not tracked:
        secho(
            f"no estimate was tracking ({others} lost or degraded): no error vs simulator truth"
            + (f" (is {map_path} a map of the simulated lab?)" if map_path is not None else ""),
            fg="yellow",
        )
        return
    T = truth_at(truth, [e.stamp for e in tracked])
    P = np.array([e.pose for e in tracked])
    err = np.hypot(*(P[:, :2] - T[:, :2]).T)
    echo(
        f"{len(P)} tracking estimates; error vs simulator truth: median {np.median(err) * 1000:.1f} mm, "
        f"max {err.max() * 1000:.1f} mm" + (f" ({others} lost or degraded, not counted)" if others else "")
    )


def _run_hooks(**kw):  # type: ignore[no-untyped-def]
    """The --mcap / --state extras (icploc.hooks); a clear error if they cannot start."""
    from icploc.hooks import RunHooks

    def warn(m: str) -> None:
        secho(f"warning: {m}", fg="yellow", err=True)

    if kw.get("mcap") is None:  # nothing of the MCAP writer is needed (its import: ~10 ms)
        return RunHooks(warn=warn, **kw)
    from icploc.mcap_export import McapError

    try:
        return RunHooks(warn=warn, **kw)
    except McapError as e:
        secho(f"error: {e}", fg="red", err=True)
        raise CommandExit(1) from None


def start_command_process() -> None:
    """Set up a process that is the ``icploc`` command (not a library user's): numpy's
    OpenBLAS starts a thread per core when numpy is imported, and on a busy machine those
    threads spin for tens of milliseconds of CPU for nothing: the command's matrices are
    3 x 3, its heavy work is the Rust core's. One BLAS thread unless the user chose
    (``OPENBLAS_NUM_THREADS`` set); a process that has numpy already keeps it as it is.

    The cyclic garbage collector runs after every 100,000 net allocations instead of 700:
    at 700 it traced the growing set of imported objects ~50 times during the command's
    start-up (~12 ms of CPU, more than the whole replay's collections), for objects that
    live as long as the process; per-scan objects are freed by reference counting (a
    whole 814-scan replay leaves ~100 objects of cyclic garbage; its peak memory grows by
    ~1 MB)."""
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    gc.set_threshold(100_000, 20, 20)


def end_command_process() -> None:
    """The command is done (its files closed, its summary printed): move every object to
    the garbage collector's permanent generation, so that the interpreter's exit tears the
    modules down without tracing tens of thousands of live objects again and again (~100 ms
    of a short replay's exit). Objects are still freed and finalized as they are released."""
    gc.freeze()


def main() -> None:
    start_command_process()
    argv = sys.argv[1:]
    try:
        code = _run_plain(argv)
        if code is None:
            # invoking one of this module's commands needs no sub-app (their imports cost
            # ~10 ms); help, a sub-app or a mistyped name gets every command
            if not (argv[:1] and argv[0] in COMMANDS.top_level()):
                _register()
            _app()()
    finally:
        end_command_process()
    sys.exit(code)


def _run_plain(argv: list[str]) -> int | None:
    """Run the command ``argv`` names without typer when its command line is plain; its
    exit code, or None: typer's to parse (and report), from the start."""
    found = COMMANDS.find(argv)
    if found is None:
        return None
    func, args = found
    kwargs = parse_plain(func, args)
    if kwargs is None:
        return None
    try:
        return run_guarded(lambda: func(**kwargs))
    except BadUsage:
        return None  # raised before the command did anything: typer reports it


if __name__ == "__main__":
    main()
