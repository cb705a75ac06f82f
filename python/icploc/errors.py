"""The one error root of icploc.

Every error icploc raises on purpose is an :class:`IcplocError`; the four families below it
say what went wrong, and each keeps the built-in base it had before (``ValueError`` for bad
input, ``RuntimeError`` / ``OSError`` for a device), so ``except ValueError`` still works::

    IcplocError
    ├── FileFormatError (ValueError)   a file is malformed: .path, .line (None: not known)
    │     MapError, LogFormatError, TopicError, TrajectoryFormatError,
    │     RecordingFormatError, StateError
    ├── ConfigError (ValueError)       a setting is invalid: .path, .field
    ├── DeviceError                    a laser / base / port misbehaves
    │     SickError, PowerBotError, PortError (OSError), SickProtocolError,
    │     ArcosProtocolError (ValueError)
    ├── UsageError (ValueError)        arguments that contradict each other (CLI)
    └── IcpError                       the Rust core's (icploc._core): InvalidInputError,
          EmptyMapError, GridTooLargeError, InvalidConfigError (all ValueError)

This module imports nothing of icploc (every module may import it; the binding makes its
``IcpError`` a subclass of :class:`IcplocError` when it is imported).
"""

from __future__ import annotations

import os

__all__ = ["ConfigError", "DeviceError", "FileFormatError", "IcplocError", "UsageError"]


class IcplocError(Exception):
    """Base class of every error icploc raises on purpose."""


class FileFormatError(IcplocError, ValueError):
    """A file (a map, a log, a trajectory, a recording, a state file) is malformed.

    ``FileFormatError(path, message, line=None)``; the text is ``path:line: message``.
    ``path`` (None: data not read from a file) and ``line`` (None: binary, or not known)
    say where; ``reason`` is the message alone."""

    path: str | None = None
    line: int | None = None
    reason: str = ""

    def __init__(
        self,
        path: str | os.PathLike[str] | None,
        message: str,
        line: int | None = None,
    ) -> None:
        self._where(path, line, message)

    def _where(self, path: str | os.PathLike[str] | None, line: int | None, message: str) -> None:
        """Set ``path`` / ``line`` / ``reason`` and the text (subclasses with their own
        constructor call this)."""
        self.path = None if path is None else os.fspath(path)
        self.line = line
        self.reason = message
        if self.path is None:
            text = message
        else:
            text = (
                f"{self.path}:{line}: {message}" if line is not None else f"{self.path}: {message}"
            )
        ValueError.__init__(self, text)


class ConfigError(IcplocError, ValueError):
    """A configuration file or value is invalid (unknown key, wrong type, out of range).

    ``path`` (the file, None for values given in code) and ``field`` (``section.key``,
    None when the problem is not one field's) say where."""

    def __init__(self, message: str, *, path: str | None = None, field: str | None = None) -> None:
        super().__init__(message)
        self.path = path
        self.field = field


class DeviceError(IcplocError):
    """A device (laser scanner, robot base, serial port) failed or answered nonsense."""


class UsageError(IcplocError, ValueError):
    """Arguments or options that cannot be used together (a command-line usage error)."""
