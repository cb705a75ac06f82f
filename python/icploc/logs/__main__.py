"""``python -m icploc.logs LOG [LOG ...]``: a shim for ``icploc log info LOG [LOG ...]`` (print
what each log holds); the command itself is in :mod:`icploc.cli`."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """Run ``icploc log info`` with ``argv``; returns the exit code."""
    import click
    import typer

    from icploc.cli import app

    args = sys.argv[1:] if argv is None else list(argv)
    cmd = typer.main.get_command(app)
    try:
        rv = cmd.main(["log", "info", *args], prog_name="python -m icploc.logs", standalone_mode=False)
    except click.ClickException as e:
        e.show()
        return e.exit_code
    except click.exceptions.Exit as e:
        return e.exit_code
    return rv if isinstance(rv, int) else 0


if __name__ == "__main__":
    raise SystemExit(main())
