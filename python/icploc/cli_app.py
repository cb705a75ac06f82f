"""The typer app of the ``icploc`` commands: :mod:`icploc.cli`'s table (declared with
:mod:`icploc.cli_args`) as typer commands, with typer's help, parsing and usage errors.

Built on first use of ``icploc.cli.app`` (help, a usage error, a command line the plain
parser declines, the tests' ``CliRunner``); a plain ``icploc replay ...`` never imports it.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Annotated, Any

import typer
from typer.core import TyperArgument, TyperGroup, TyperOption

from icploc.cli_args import (
    Argument,
    BadUsage,
    CommandExit,
    Commands,
    Option,
    guard_exit_code,
    split,
)


class _Argument(TyperArgument):
    """A positional argument shown as ``LOG`` (required) or ``[LOG]`` in the usage line,
    not typer's ``{log}``."""

    def _usage_display_name(self) -> str:
        name = self.metavar or (self.name or "").upper()
        if self.nargs != 1:
            name += "..."
        return name if self.required else f"[{name}]"


def _tidy_help(cmd: Any, ctx: Any) -> None:
    """The help of one command as a user reads it: arguments upper case (``LOG``, not
    ``{log}``), no ``<bool>`` type for a flag (it takes no value; --help included)."""
    for p in cmd.get_params(ctx):
        if type(p) is TyperArgument:
            p.__class__ = _Argument
            if p.metavar is None and p.name:
                p.metavar = p.name.upper()
        elif isinstance(p, TyperOption) and p.is_flag and p.metavar is None:
            p.metavar = ""


class Guarded(TyperGroup):
    """Every command: a user error (OSError, ValueError) becomes one ``error: ...`` line and
    exit 1, Ctrl-C exit 130, instead of a traceback (:func:`icploc.cli_args.guard_exit_code`,
    as a plain run does); every command's help tidied (:func:`_tidy_help`)."""

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        cmd = super().get_command(ctx, cmd_name)
        if cmd is not None:
            _tidy_help(cmd, ctx)
        return cmd

    def get_help(self, ctx: Any) -> str:
        _tidy_help(self, ctx)
        return super().get_help(ctx)

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except (KeyboardInterrupt, MemoryError, OSError, ValueError) as e:
            code = guard_exit_code(e)
            assert code is not None
            raise typer.Exit(code) from None


def _typer_annotation(annotation: Any) -> Any:
    base, info = split(annotation)
    if isinstance(info, Option):
        return Annotated[base, typer.Option(*info.decls, help=info.help, min=info.min, max=info.max)]
    if isinstance(info, Argument):
        return Annotated[base, typer.Argument(help=info.help)]
    return annotation


def callback(func: Callable[..., None]) -> Callable[..., None]:
    """``func`` as a typer command: the same name, help and parameters, with typer's
    declarations; its :class:`CommandExit` / :class:`BadUsage` as typer's ``Exit`` /
    ``BadParameter``."""
    sig = inspect.signature(func, eval_str=True)
    params = [p.replace(annotation=_typer_annotation(p.annotation)) for p in sig.parameters.values()]

    def run(**kwargs: Any) -> None:
        try:
            func(**kwargs)
        except CommandExit as e:
            raise typer.Exit(e.code) from None
        except BadUsage as e:
            raise typer.BadParameter(e.message, param_hint=e.param_hint) from None

    run.__name__, run.__qualname__, run.__doc__ = func.__name__, func.__qualname__, func.__doc__
    run.__module__ = func.__module__
    run.__signature__ = sig.replace(parameters=params, return_annotation=None)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in params}
    return run


def build(commands: Commands, help: str) -> typer.Typer:
    """The typer app of a command table: its groups, then its commands in their order."""
    app = typer.Typer(
        name="icploc",
        help=help,
        cls=Guarded,
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
    )
    groups: dict[str, typer.Typer] = {}
    for name, group_help in commands.groups.items():
        groups[name] = typer.Typer(help=group_help, no_args_is_help=True, cls=Guarded)
        app.add_typer(groups[name], name=name)
    for path, func in commands.entries:
        (groups[path[0]] if len(path) == 2 else app).command(path[-1])(callback(func))
    return app
