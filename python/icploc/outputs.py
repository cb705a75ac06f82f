"""Output files that cannot destroy inputs: checks made before any work starts.

:func:`check_outputs` refuses an output path that resolves to an input (the log, the map,
the image a ROS map YAML names, the config, the truth) or to another output, and one that
cannot be written (missing directory, a directory, no permission). :func:`map_inputs`
lists the files a map path reads.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from icploc.errors import UsageError
from icploc.flat_yaml import plain_mapping

__all__ = ["OutputClashError", "OutputError", "check_outputs", "map_inputs"]


class OutputError(UsageError):
    """An output path is unusable: it is an input, a duplicate, or cannot be written."""


class OutputClashError(OutputError):
    """An output path is one of the inputs or another output (a usage error)."""


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)  # hard links, bind mounts, case-folding file systems
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def map_inputs(path: str | os.PathLike[str]) -> list[Path]:
    """The files a map path reads: itself, and for a ROS map YAML the image it names."""
    p = Path(path)
    out = [p]
    if p.suffix.lower() in (".yaml", ".yml") and p.is_file():
        try:
            with open(p, "rb") as fh:
                raw = fh.read(1 << 20)
        except OSError:
            return out  # the map loader reports what is wrong with it
        try:
            data: Any = plain_mapping(raw.decode("utf-8"))
        except UnicodeDecodeError:
            data = None
        if data is None:  # not a flat file of plain keys and values: PyYAML reads it
            import yaml

            try:
                data = yaml.safe_load(raw)
            except (ValueError, yaml.YAMLError):
                return out
        img = data.get("image") if isinstance(data, dict) else None
        if isinstance(img, str) and img:
            ip = Path(img)
            out.append(ip if ip.is_absolute() else p.parent / ip)
    return out


def check_writable(what: str, path: Path) -> None:
    """Raise :class:`OutputError` unless ``path`` can be created or overwritten as a file."""
    if path.is_dir():
        raise OutputError(f"{what} {path}: is a directory")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{what} {path}: directory {parent} does not exist")
    if path.exists():
        if not os.access(path, os.W_OK):
            raise OutputError(f"{what} {path}: not writable (permission denied)")
    elif not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {path}: cannot create a file in {parent} (permission denied)")


def check_outputs(
    outputs: Mapping[str, str | os.PathLike[str] | None],
    inputs: Iterable[str | os.PathLike[str] | None] | Mapping[str, str | os.PathLike[str] | None],
) -> None:
    """Refuse, before any work starts, an output (name → path; None: not written) that
    is one of ``inputs`` (paths, or label → path) or another output
    (:class:`OutputClashError`), or that cannot be written (:class:`OutputError`)."""
    if isinstance(inputs, Mapping):
        ins = [(f"the {k}", Path(v)) for k, v in inputs.items() if v is not None]
    else:
        ins = [("an input", Path(v)) for v in inputs if v is not None]
    seen: list[tuple[str, Path]] = []
    for what, raw in outputs.items():
        if raw is None:
            continue
        p = Path(raw)
        for label, q in ins:
            if _same(p, q):
                raise OutputClashError(f"{what} {p} is {label} ({q}); refusing to overwrite it")
        for other, q in seen:
            if _same(p, q):
                raise OutputClashError(
                    f"{what} and {other} are the same file ({p}); give each output its own path"
                )
        check_writable(what, p)
        seen.append((what, p))
