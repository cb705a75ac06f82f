"""The typer app of the ``icploc`` commands: :mod:`icploc.cli`'s table (declared with
:mod:`icploc.cli_args`) as typer commands, with typer's help, parsing and usage errors.

Built on first use of ``icploc.cli.app`` (help, a usage error, a command line the plain
parser declines, the sub-apps, the tests' ``CliRunner``); a plain ``icploc replay ...``
never imports it.

typer 0.29 converts every option's value with a pydantic ``TypeAdapter`` built on first
use, so any command through typer (``--help`` included) imports pydantic (~70 ms of CPU).
:func:`_build_runtime_param` converts the plain values of the plain types instead (a
string, a path, a flag, a decimal number in its bounds, lists of strings or paths),
exactly as typer does, and hands anything else (a value to refuse, another type) to
typer's own, pydantic and its error messages included. tests/test_cli_plain.py compares
the two. ``ICPLOC_TYPER_PYDANTIC=1`` leaves typer's own in place.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, get_args, get_origin

import typer
import typer.core
from typer.core import TyperArgument, TyperGroup, TyperOption

from icploc.cli_args import (
    DECLINE,
    Argument,
    BadUsage,
    CommandExit,
    Commands,
    Option,
    guard_exit_code,
    plain_float,
    plain_int,
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


# ----------------------------------------------------------------- typer's value coercion

try:  # typer 0.29's private coercion layer; without it typer's own is used as it is
    from typer._coercion import RuntimeParam, TypeDescriptor
    from typer._param_types import coerce_cli_path

    _TYPER_BUILD: Any = typer.core.build_runtime_param  # type: ignore[attr-defined]
except (ImportError, AttributeError):  # pragma: no cover - another typer
    RuntimeParam = None  # type: ignore[assignment,misc]

_PLAIN_TYPES = (str, Path, int, float, bool)


def _path_flags_are_default(info: Any) -> bool:
    return (
        getattr(info, "path_type", None) is None
        and not getattr(info, "resolve_path", False)
        and not getattr(info, "allow_dash", False)
    )


def _handles(d: Any) -> bool:
    """A parameter whose plain values :func:`_plain_value` converts."""
    info, ann = d.parameter_info, d.annotation
    if d.file_annotation is not None or info.parser is not None or info.clamp:
        return False
    if get_origin(ann) is list:
        args = get_args(ann)
        if len(args) != 1 or args[0] not in (str, Path):
            return False
        ann = args[0]
    return ann in _PLAIN_TYPES and (ann is not Path or _path_flags_are_default(info))


def _in_bounds(info: Any, value: float) -> bool:
    return (info.min is None or value >= info.min) and (info.max is None or value <= info.max)


def _plain_value(ann: Any, info: Any, value: Any, param: Any, ctx: Any) -> Any:
    """``value`` as typer converts it for ``ann``, or ``DECLINE`` (typer's own then)."""
    if ann is str:
        return value if type(value) is str else DECLINE
    if ann is bool:
        return value if type(value) is bool else DECLINE
    if ann is Path:
        if isinstance(value, Path):
            return coerce_cli_path(value, info, path_type=Path, param=param, ctx=ctx)
        if type(value) is not str or "\x00" in value:
            return DECLINE
        return coerce_cli_path(Path(value), info, path_type=Path, param=param, ctx=ctx)
    if ann is int:
        if type(value) is int:
            got: float = value
        elif type(value) is str and plain_int(value):
            got = int(value)
        else:
            return DECLINE
    else:
        if type(value) is float:
            got = value
        elif type(value) is str and plain_float(value):
            got = float(value)
        else:
            return DECLINE
    return got if _in_bounds(info, got) else DECLINE


if RuntimeParam is not None:

    @dataclass(frozen=True)
    class _PlainRuntimeParam(RuntimeParam):  # type: ignore[misc,valid-type]
        descriptor: TypeDescriptor

        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:
            ann, info = self.annotation, self.parameter_info
            if get_origin(ann) is list:
                if isinstance(value, (list, tuple)):
                    item = get_args(ann)[0]
                    got: Any = [_plain_value(item, info, v, param, ctx) for v in value]
                    if not any(g is DECLINE for g in got):
                        return got
            else:
                try:
                    got = _plain_value(ann, info, value, param, ctx)
                except (TypeError, AttributeError):  # typer's private helpers changed: its own way
                    got = DECLINE
                if got is not DECLINE:
                    return got
            return _TYPER_BUILD(self.descriptor)._coerce_value(value, param=param, ctx=ctx)

    def _build_runtime_param(descriptor: Any) -> Any:
        """typer's ``build_runtime_param`` without pydantic for the plain types."""
        try:
            if _handles(descriptor):
                return _PlainRuntimeParam(
                    parameter_info=descriptor.parameter_info,
                    annotation=descriptor.annotation,
                    descriptor=descriptor,
                )
        except (TypeError, AttributeError):  # typer's private layer changed: its own way
            pass
        return _TYPER_BUILD(descriptor)

    if os.environ.get("ICPLOC_TYPER_PYDANTIC") != "1":  # 1: typer's own, for comparison
        typer.core.build_runtime_param = _build_runtime_param  # type: ignore[attr-defined]
