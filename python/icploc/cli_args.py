"""The ``icploc`` commands' declarations, their output and exits, and a plain argument
parser: all without typer (or click, or pydantic), so that ``icploc replay ...`` starts in
milliseconds.

A command is a function registered in a :class:`Commands` table, each parameter annotated
``Annotated[TYPE, Option("--name", help=...)]`` or ``Annotated[TYPE, Argument(help=...)]``
with its default after ``=`` (typer's style). That is the ONE declaration of each option.
:mod:`icploc.cli_app` turns the table into the typer app: help, shell-style parsing, every
usage error worded and exited as typer does.

:func:`parse_plain` reads a plain, well-formed command line for the same function as typer
would, or declines (returns None) and the command goes through typer instead: ``--help``,
``--``, an unknown, repeated or misspelt option, a missing value or a missing required one, a
value it does not convert exactly as typer does (a number it does not recognise, one out of
range), a list option. tests/test_cli_plain.py checks the two agree on generated command
lines.

A command writes with :func:`echo` / :func:`secho` (click's: a line to stdout or stderr,
colour only on a terminal), ends with ``raise CommandExit(code)`` and reports a bad option
value with ``raise BadUsage(message, param_hint="--name")`` (typer's ``BadParameter``),
before it does any work: a plain run then hands the command line to typer, which runs the
command again and reports the error as before.
"""

from __future__ import annotations

import inspect
import os
import sys
import types
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Union, get_args, get_origin

#: exit codes (also in ``icploc --help``)
EXIT_OK = 0  #: done
EXIT_ERROR = 1  #: an error: a missing or malformed file, a bad value in it, a write error
EXIT_USAGE = 2  #: bad usage: an unknown option, a bad option value, a bad config file
EXIT_LOST = 3  #: replay finished but lost more than --max-lost of its scans
EXIT_INTERRUPTED = 130  #: stopped by Ctrl-C (the files written so far are complete)

__all__ = [
    "Annotated",
    "Argument",
    "BadUsage",
    "CommandExit",
    "Commands",
    "Option",
    "echo",
    "parse_plain",
    "run_guarded",
    "secho",
]


class Option:
    """An option: its names (default ``--param-name``; a bool's default is the pair
    ``--name/--no-name``), its help, and for a number its bounds (inclusive)."""

    __slots__ = ("decls", "help", "max", "min")

    def __init__(
        self, *decls: str, help: str | None = None, min: float | None = None, max: float | None = None
    ) -> None:
        self.decls, self.help, self.min, self.max = decls, help, min, max


class Argument:
    """A positional argument (shown as ``NAME`` in the usage line)."""

    __slots__ = ("help",)

    def __init__(self, *, help: str | None = None) -> None:
        self.help = help


class CommandExit(Exception):
    """End the command with exit code ``code`` (typer's ``Exit``)."""

    def __init__(self, code: int = EXIT_OK) -> None:
        super().__init__(code)
        self.code = code


class BadUsage(Exception):
    """A bad option value or a contradiction between options (typer's ``BadParameter``:
    exit 2 with the command's usage line). Raise it before the command does any work."""

    def __init__(self, message: str, param_hint: str | None = None) -> None:
        super().__init__(message)
        self.message, self.param_hint = message, param_hint


_COLOURS = {"red": 31, "green": 32, "yellow": 33}


def echo(message: object = "", *, err: bool = False, nl: bool = True) -> None:
    """One line (``nl``) to stdout, or stderr with ``err``, flushed (click's ``echo``)."""
    stream = sys.stderr if err else sys.stdout
    if stream is None:
        return
    stream.write(f"{message}\n" if nl else f"{message}")
    stream.flush()


def secho(message: object, *, fg: str | None = None, err: bool = False) -> None:
    """:func:`echo` in colour ``fg`` on a terminal, plain text elsewhere (click's ``secho``)."""
    stream = sys.stderr if err else sys.stdout
    text = str(message)
    if fg is not None and stream is not None and _isatty(stream):
        text = f"\x1b[{_COLOURS[fg]}m{text}\x1b[0m"
    echo(text, err=err)


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def describe(e: BaseException) -> str:
    """One line for an OSError / ValueError, naming the file where there is one."""
    if isinstance(e, OSError) and e.filename is not None:
        return f"{e.filename}: {e.strerror or e}"
    return str(e) or type(e).__name__


def fail(message: str) -> int:
    """Print ``error: message`` (red on a terminal) to stderr; the exit code of an error."""
    secho(f"error: {message}", fg="red", err=True)
    return EXIT_ERROR


def guard_exit_code(e: BaseException) -> int | None:
    """What every command does with an exception it did not handle: a user error (OSError,
    ValueError) is one ``error: ...`` line and exit 1, Ctrl-C exit 130, no memory exit 1;
    None: not one of those (a bug: its traceback is shown)."""
    if isinstance(e, KeyboardInterrupt):
        secho("interrupted", fg="yellow", err=True)
        return EXIT_INTERRUPTED
    if isinstance(e, MemoryError):
        return fail("out of memory (is the input far larger than it should be?)")
    if isinstance(e, (OSError, ValueError)):
        return fail(describe(e))
    return None


def run_guarded(call: Callable[[], object]) -> int:
    """Run a command's body as the typer app does (:func:`guard_exit_code`); its exit code.
    :class:`BadUsage` propagates (the caller hands the command line to typer)."""
    try:
        call()
    except CommandExit as e:
        return e.code
    except (KeyboardInterrupt, MemoryError, OSError, ValueError) as e:
        code = guard_exit_code(e)
        assert code is not None
        return code
    return EXIT_OK


class Commands:
    """The table of commands: ``@commands.command()`` registers a function under its name
    (``_`` -> ``-``) or the given one, in a group made with :meth:`group`."""

    def __init__(self) -> None:
        self.groups: dict[str, str] = {}  #: group name -> its help
        self.entries: list[tuple[tuple[str, ...], Callable[..., None]]] = []

    def group(self, name: str, help: str) -> None:
        """A group of commands (``icploc config ...``) and its help."""
        self.groups[name] = help

    def command(self, name: str | None = None, *, group: str | None = None) -> Callable[[Any], Any]:
        def register(func: Callable[..., None]) -> Callable[..., None]:
            path = (name or func.__name__.replace("_", "-"),)
            self.entries.append(((group, *path) if group else path, func))
            return func

        return register

    def find(self, argv: list[str]) -> tuple[Callable[..., None], list[str]] | None:
        """The command an argument list names, and the arguments after its name."""
        for path, func in self.entries:
            if argv[: len(path)] == list(path):
                return func, argv[len(path) :]
        return None

    def top_level(self) -> set[str]:
        """The names of the top-level commands and groups."""
        return {path[0] for path, _f in self.entries} | set(self.groups)


# ---------------------------------------------------------------------------- plain parsing


class _Param:
    """One parameter of a command as the plain parser sees it."""

    __slots__ = ("base", "default", "flags", "is_arg", "max", "min", "name", "optional", "supported")

    def __init__(self, p: inspect.Parameter) -> None:
        self.name = p.name
        self.default = p.default
        annotation, info = split(p.annotation)
        self.is_arg = isinstance(info, Argument)
        args = get_args(annotation)
        self.optional = get_origin(annotation) in (Union, types.UnionType) and type(None) in args
        base = next(a for a in args if a is not type(None)) if self.optional else annotation
        self.base = base
        # a parameter without Option / Argument is typer's to read (an argument or an option
        # by its default): not read plainly
        self.supported = (
            info is not None
            and base in (str, Path, int, float, bool)
            and not (self.is_arg and base is bool)
        )
        self.min = getattr(info, "min", None)
        self.max = getattr(info, "max", None)
        #: option name -> the value it sets (a flag's True / False; None: takes a value)
        self.flags: dict[str, bool | None] = {}
        if not self.is_arg:
            decls = getattr(info, "decls", ()) or (f"--{p.name.replace('_', '-')}",)
            if base is bool and not getattr(info, "decls", ()):
                decls = (f"{decls[0]}/--no-{decls[0][2:]}",)
            for d in decls:
                on, _slash, off = d.partition("/")
                self.flags[on.strip()] = True if base is bool else None
                if off:
                    self.flags[off.strip()] = False


def split(annotation: Any) -> tuple[Any, Option | Argument | None]:
    if get_origin(annotation) is Annotated:
        base, *extra = get_args(annotation)
        return base, next((e for e in extra if isinstance(e, (Option, Argument))), None)
    return annotation, None


_PARAMS: dict[Callable[..., Any], list[_Param]] = {}


def params(func: Callable[..., Any]) -> list[_Param]:
    """A command's parameters (its annotations evaluated once)."""
    got = _PARAMS.get(func)
    if got is None:
        sig = inspect.signature(func, eval_str=True)
        got = _PARAMS[func] = [_Param(p) for p in sig.parameters.values()]
    return got


#: what a converter returns for a value it is not sure of (typer then reads it)
DECLINE = object()


def _digits(s: str) -> bool:
    return s != "" and s.isascii() and s.isdigit()


def plain_int(text: str) -> bool:
    """``-?(0|[1-9][0-9]*)``, at most 18 digits (matched by hand: compiling a regular
    expression costs more than the whole parse)."""
    s = text[1:] if text[:1] == "-" else text
    return _digits(s) and len(s) <= 18 and (s == "0" or s[0] != "0")


def plain_float(text: str) -> bool:
    """``-?([0-9]+(\\.[0-9]*)?|\\.[0-9]+)([eE][-+]?[0-9]+)?``, at most 40 characters."""
    s = text[1:] if text[:1] == "-" else text
    mantissa, e, exponent = s.replace("E", "e").partition("e")
    whole, dot, frac = mantissa.partition(".")
    if e and not _digits(exponent[1:] if exponent[:1] in ("+", "-") else exponent):
        return False
    return len(text) <= 40 and (_digits(whole) or (whole == "" and _digits(frac))) and (
        frac == "" or _digits(frac)
    )


def _convert(p: _Param, text: str) -> Any:
    """``text`` as typer converts it for ``p``, or ``DECLINE`` where it is not sure."""
    if p.base is str:
        return text
    if p.base is Path:
        # typer's path check (click.Path, readable=True) refuses an existing unreadable path
        if "\x00" in text or (os.path.lexists(text) and not os.access(text, os.R_OK)):
            return DECLINE
        return Path(text)
    if p.base is int:
        if not plain_int(text):
            return DECLINE
        value: float = int(text)
    else:
        if not plain_float(text):
            return DECLINE
        value = float(text)
    if (p.min is not None and not value >= p.min) or (p.max is not None and not value <= p.max):
        return DECLINE
    return value


def parse_plain(func: Callable[..., Any], args: list[str]) -> dict[str, Any] | None:
    """The keyword arguments typer would call ``func`` with for the command line ``args``
    (after the command's name), or None: not a plain, well-formed command line (see the
    module's doc), for typer to parse and report."""
    ps = params(func)
    if not all(p.supported for p in ps):
        return None
    by_name = {name: p for p in ps for name in p.flags}
    values: dict[str, Any] = {}
    positional: list[str] = []
    i = 0
    while i < len(args):
        a = args[i]
        i += 1
        if a[:1] != "-" or a == "-":
            positional.append(a)
            continue
        name, eq, text = a.partition("=")
        p = by_name.get(name)
        if p is None or p.name in values or a == "--help":
            return None
        flag = p.flags[name]
        if flag is not None:  # a bool flag takes no value
            if eq:
                return None
            values[p.name] = flag
            continue
        if not eq:
            if i == len(args):
                return None
            text = args[i]
            i += 1
        v = _convert(p, text)
        if v is DECLINE:
            return None
        values[p.name] = v
    for p in ps:
        if p.is_arg:
            if positional:
                v = _convert(p, positional.pop(0))
                if v is DECLINE:
                    return None
                values[p.name] = v
            elif p.default is inspect.Parameter.empty:
                return None
            else:
                values[p.name] = p.default
        elif p.name not in values:
            if p.default is inspect.Parameter.empty:
                return None
            values[p.name] = p.default
    if positional:  # more than the command takes
        return None
    return values
