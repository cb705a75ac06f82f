"""The cache of prepared maps: a grid map is fitted once, later loads read the result.

Entries live in ``$XDG_CACHE_HOME/icploc/maps`` (``~/.cache/icploc/maps`` when the variable
is unset or not absolute), one uncompressed ``.npz`` per key. The key is a hash of the map
file's bytes, its image's bytes, the preparation settings and the version of the fitting
code, so editing the map, its image or a setting makes a new entry and never reads a stale
one. The cache is an optimisation only: an unreadable, corrupt or unwritable cache never
breaks a load. The load falls back to fitting and warns once per process.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .map import Map

#: bump when the fitting or the stored layout changes (invalidates every entry)
FIT_VERSION = 3

_warned = False


def cache_dir() -> Path:
    """The directory of cached prepared maps (XDG base directory rules)."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    root = Path(base) if base and os.path.isabs(base) else Path.home() / ".cache"
    return root / "icploc" / "maps"


def _warn_once(message: str) -> None:
    global _warned
    if not _warned:
        _warned = True
        warnings.warn(f"map cache: {message}; loading without it", RuntimeWarning, stacklevel=3)


def cache_key(files: Iterable[Path], settings: dict[str, Any]) -> str:
    """Content hash of ``files`` plus the settings and the fitting-code version."""
    from icploc import __version__

    h = hashlib.blake2b(digest_size=20)
    h.update(f"icploc {__version__} fit {FIT_VERSION}\n".encode())
    h.update(json.dumps(settings, sort_keys=True, default=str).encode())
    for f in files:
        data = Path(f).read_bytes()
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)
    return h.hexdigest()


def load_cached(key: str, source: str) -> Map | None:
    """The cached map for ``key``, or None (absent, or unusable: then warn once)."""
    from .errors import MapError
    from .prepared import load_prepared

    path = cache_dir() / f"{key}.npz"
    if not path.is_file():
        return None
    try:
        m = load_prepared(path)
    except (MapError, OSError, ValueError, KeyError, EOFError) as e:
        _warn_once(f"ignoring unreadable entry {path} ({e})")
        return None
    m.source = source
    m.meta.pop("prepared", None)
    m.meta["cache"] = str(path)
    return m


def store(key: str, m: Map) -> None:
    """Write ``m`` under ``key`` (atomically); a failure only warns (once)."""
    from .prepared import save_prepared

    d = cache_dir()
    tmp = None
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=d, prefix=".tmp-", suffix=".npz")
        os.close(fd)
        save_prepared(m, tmp, [], compress=False)
        os.replace(tmp, d / f"{key}.npz")
        tmp = None
    except OSError as e:
        _warn_once(f"cannot write to {d} ({e.strerror or e})")
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
