"""The ``icploc`` command line (typer)."""

from __future__ import annotations

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


def main() -> None:
    _register()
    app()


if __name__ == "__main__":
    main()
