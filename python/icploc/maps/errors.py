"""The one exception type of the maps package."""

from __future__ import annotations

from pathlib import Path


class MapError(ValueError):
    """A map file (or map data) is invalid.

    The message names the file (when there is one) and the offending field, e.g.
    ``maps/office.yaml: field 'resolution': must be a positive finite number, got nan``.
    ``path`` and ``field`` are also available as attributes.
    """

    def __init__(self, path: str | Path | None, field: str | None, problem: str) -> None:
        self.path = None if path is None else str(path)
        self.field = field
        self.problem = problem
        where = self.path if self.path is not None else "<map>"
        what = f"field '{field}': " if field else ""
        super().__init__(f"{where}: {what}{problem}")
