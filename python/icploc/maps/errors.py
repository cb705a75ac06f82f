"""The one exception type of the maps package."""

from __future__ import annotations

from pathlib import Path

from icploc.errors import FileFormatError


class MapError(FileFormatError):
    """A map file (or map data) is invalid.

    The message names the file (when there is one) and the offending field, e.g.
    ``maps/office.yaml: field 'resolution': must be a positive finite number, got nan``.
    ``path`` and ``field`` are also available as attributes.
    """

    def __init__(self, path: str | Path | None, field: str | None, problem: str) -> None:
        self.field = field
        self.problem = problem
        what = f"field '{field}': " if field else ""
        self._where("<map>" if path is None else path, None, f"{what}{problem}")
        if path is None:
            self.path = None
