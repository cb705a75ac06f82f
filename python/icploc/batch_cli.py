"""The ``icploc batch`` command (registered by :mod:`icploc.cli`; the work is in
:mod:`icploc.batch`)."""

from __future__ import annotations

from pathlib import Path

from icploc.cli_args import Annotated, Argument, CommandExit, Option, echo, secho


def _load_config(path: Path | None):  # type: ignore[no-untyped-def]
    from icploc.cli import _load_config as load

    return load(path)


def batch(
    logs: Annotated[
        list[Path], Argument(help="Logs to replay (any format icploc replay reads)")
    ],
    map_path: Annotated[Path, Option("--map", help="Map file (one map for all logs)")],
    out: Annotated[Path, Option("--out", help="Output directory")],
    scheduler: Annotated[
        str | None,
        Option("--scheduler", help="Dask scheduler address (default: a local cluster)"),
    ] = None,
    workers: Annotated[
        int | None,
        Option("--workers", help="Local cluster workers; default: one per core (count)"),
    ] = None,
    truth_dir: Annotated[
        Path | None,
        Option("--truth-dir", help="Directory of <log stem>.tum true trajectories"),
    ] = None,
    config: Annotated[Path | None, Option("--config", help="Localizer config (YAML)")] = None,
    progress: Annotated[bool, Option(help="Show a progress bar")] = True,
) -> None:
    """Replay many logs against one map in parallel on Dask (needs the fleet extra: Dask distributed)."""
    from icploc.batch import BatchError, batch_replay

    cfg = _load_config(config)
    try:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        with Progress(TextColumn("[bold]batch"), BarColumn(), MofNCompleteColumn(), TextColumn("logs"),
                      TimeElapsedColumn(), transient=True, disable=not progress) as bar:  # fmt: skip
            task = bar.add_task("batch", total=len(logs))

            def on_progress(done: int, total: int, row) -> None:  # type: ignore[no-untyped-def]
                bar.update(task, completed=done)
                if row.error:
                    bar.console.print(f"[red]{row.log}: {row.error}")

            res = batch_replay(logs, map_path, out, config=cfg, scheduler=scheduler, workers=workers,
                               truth_dir=truth_dir, on_progress=on_progress)  # fmt: skip
    except (BatchError, OSError, ValueError) as e:
        secho(f"error: {e}", fg="red", err=True)
        raise CommandExit(1) from None
    ok = len(res.rows) - len(res.failed)
    scans = sum(r.scans for r in res.rows)
    echo(
        f"{ok}/{len(res.rows)} logs, {scans} scans in {res.wall_time:.1f} s; summary: {res.summary}"
    )
    if res.failed:
        raise CommandExit(3)
