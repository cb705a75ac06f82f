"""``python -m icploc.logs LOG [LOG ...]``: a shim for ``icploc log info LOG [LOG ...]`` (print
what each log holds); the command itself is in :mod:`icploc.cli`."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """Run ``icploc log info`` with ``argv``; returns the exit code."""
    import typer

    from icploc.cli import app

    args = sys.argv[1:] if argv is None else list(argv)
    root = typer.main.get_command(app)
    group = root.get_command(typer.Context(root), "log")  # type: ignore[attr-defined]
    cmd = group.get_command(typer.Context(group), "info")
    try:
        cmd.main(args, prog_name="python -m icploc.logs")
    except SystemExit as e:  # click's standalone mode ends every run with one
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
