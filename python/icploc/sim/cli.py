"""``icploc sim``: the device simulators from the command line.

``icploc sim serve`` runs a simulated SICK PLS and PowerBot (:class:`SimSession`) on two
pseudo-terminals in a 10 m x 8 m room with walking people, prints the two ports to open
(``icploc run --laser PORT --base PORT``, or any serial tool) and serves them until
Ctrl-C (or ``--duration``).
"""

from __future__ import annotations

from typing import Annotated

import typer

sim_app = typer.Typer(
    help="Device simulators (a SICK PLS and a PowerBot on pseudo-terminals).",
    no_args_is_help=True,
)


@sim_app.command("serve")
def serve(
    people: Annotated[int, typer.Option(min=0, help="People walking in the room (count)")] = 2,
    seed: Annotated[int, typer.Option(help="Seed of the people, the noise and the faults (an integer)")] = 0,
    fast: Annotated[
        bool, typer.Option("--fast", help="Test mode: send as fast as the host reads, not in real time")
    ] = False,
    drive: Annotated[
        bool,
        typer.Option("--drive", help="Drive a built-in square plan instead of obeying host commands"),
    ] = False,
    duration: Annotated[
        float | None, typer.Option(min=0.0, help="Stop after this long (s; default: at Ctrl-C)")
    ] = None,
) -> None:
    """Run a simulated SICK PLS and PowerBot in a 10 m x 8 m room until Ctrl-C, printing
    the two ports to open. The robot starts at (1.5 m, 1.5 m, 0 rad) and obeys the
    PowerBot driver's velocity commands (or, with --drive, drives a square by itself)."""
    import time

    from icploc.sim.powerbot_device import waypoint_plan
    from icploc.sim.scenes import box
    from icploc.sim.session import SimSession

    world = box(10.0, 8.0)
    world.add_random_people(people, seed=seed)
    plan = waypoint_plan([(8.0, 0.5, 0.0), (3.14, 0.0, 0.5)] * 4) if drive else None
    with SimSession(world, start_pose=(1.5, 1.5, 0.0), plan=plan, realtime=not fast, seed=seed) as sim:
        typer.echo(f"laser (SICK PLS):  {sim.laser_port}")
        typer.echo(f"base  (PowerBot):  {sim.base_port}")
        end = None if duration is None else time.monotonic() + duration
        try:
            while end is None or time.monotonic() < end:
                time.sleep(0.05 if end is not None else 1.0)
        except KeyboardInterrupt:
            pass
        if sim.errors:
            for e in sim.errors:
                typer.secho(f"error: simulator stopped: {e}", fg="red", err=True)
            raise typer.Exit(1)
