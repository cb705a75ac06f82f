"""The cache of prepared maps: a grid map is fitted once, later loads read the result.

Entries live in ``$XDG_CACHE_HOME/icploc/maps`` (``~/.cache/icploc/maps`` when the variable
is unset or not absolute), one uncompressed ``.npz`` per key. The key is a hash of the map
file's bytes, its image's bytes, the preparation settings and the version of the fitting
code, so editing the map, its image or a setting makes a new entry and never reads a stale
one. The cache is an optimisation only: an unreadable, corrupt or unwritable cache never
breaks a load. The load falls back to fitting and warns once per process.

Beside an entry, ``<key>.index-s<spacing>-r<resolution>-v<version>.npz`` keeps the cells of
the closest-point grid of the map's :class:`icploc.MapIndex` at that sample spacing (the
largest part of building the index, ~0.1 s for a 60 m building), as runs, with a hash of the
sample points and normals they belong to: :meth:`icploc.Map.index` of a map that came from
(or went into) the cache rebuilds its index from them (:func:`load_index`) and the answers
are the same. Points that differ from the hashed ones, cells that do not fit the grid the
points give, or a different grid-code version (in the name) mean the file is not used.

Beside it too, ``<key>.field-s<spacing>-r<resolution>-v<version>.npz`` keeps the distances
of the likelihood field of the global search (:class:`icploc.GlobalLocalizer`) over that
index at that grid resolution (~1.4 M nearest-point queries for a 60 m building): the
relocalization's deferred build (:func:`global_localizer`) rebuilds the localizer from them
and its answers are the same. The settings of the search do not enter the distances (its
sigma, pyramid and clearance are computed from them each time), only the map's points
(hashed, checked on load), the resolution and the field-code version do.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

try:  # hashlib's own blake2b, without hashlib's import of OpenSSL (~4 ms of a replay's start)
    from _blake2 import blake2b
except ImportError:  # pragma: no cover (an interpreter without the built-in module)
    from hashlib import blake2b

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from icploc._core import GlobalLocalizer, MapIndex

    from .map import Map

#: bump when the fitting or the stored layout changes (invalidates every entry)
FIT_VERSION = 3

_warned = False
#: attribute of a Map loaded from (or stored into) the cache: the path of its entry
_ENTRY = "_icploc_cache_entry"
#: id of a MapIndex of a cached map -> (the index, its entry, its spacing): where its
#: likelihood field is kept (the newest few; the index is held so that its id stays its own)
_INDEXES: dict[int, tuple[Any, Path, float]] = {}
_MAX_INDEXES = 16


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
    from icploc._core import __version__

    h = blake2b(digest_size=20)
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
    setattr(m, _ENTRY, path)  # noqa: B010 (not a Map attribute: the cache's own mark)
    return m


def _write_atomic(path: Path, write: Callable[[str], object]) -> bool:
    """Write ``path`` atomically: ``write(tmp)`` fills a temporary file in the same folder,
    which then replaces ``path``. A failure only warns (once) and leaves no temporary file
    behind; returns whether ``path`` was written."""
    import tempfile

    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
        os.close(fd)
        write(tmp)
        os.replace(tmp, path)
        tmp = None
        return True
    except OSError as e:
        _warn_once(f"cannot write to {path.parent} ({e.strerror or e})")
        return False
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass


def store(key: str, m: Map) -> None:
    """Write ``m`` under ``key`` (atomically); a failure only warns (once)."""
    from .prepared import save_prepared

    path = cache_dir() / f"{key}.npz"
    if _write_atomic(path, lambda tmp: save_prepared(m, tmp, [], compress=False)):
        setattr(m, _ENTRY, path)  # noqa: B010


def _index_path(entry: Path, spacing: float, resolution: float) -> Path:
    from icploc._core import GRID_FILL_VERSION

    return entry.with_name(
        f"{entry.stem}.index-s{spacing!r}-r{resolution!r}-v{GRID_FILL_VERSION}.npz"
    )


def _digest(points: NDArray[Any], normals: NDArray[Any]) -> bytes:
    import numpy as np

    h = blake2b(digest_size=20)
    for a in (points, normals):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.digest()


def load_index(
    m: Map, spacing: float, points: NDArray[Any], normals: NDArray[Any]
) -> MapIndex | None:
    """The default :class:`icploc.MapIndex` of ``points`` / ``normals`` (``m.sample(spacing)``)
    with its closest-point grid from the file beside ``m``'s cache entry; None when ``m`` is
    not from the cache, there is no file, or it is for other points (a file that cannot be
    used warns once)."""
    entry = getattr(m, _ENTRY, None)
    if entry is None:
        return None
    import zipfile

    import numpy as np

    from icploc._core import DEFAULT_CACHE_RESOLUTION, IcpError, index_from_grid_runs

    path = _index_path(entry, spacing, DEFAULT_CACHE_RESOLUTION)
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            if z["digest"].tobytes() != _digest(points, normals):
                return None  # another map's points (refitted, edited): rebuilt and replaced
            if float(z["resolution"]) != DEFAULT_CACHE_RESOLUTION:
                raise ValueError(f"grid resolution {float(z['resolution'])!r}")
            idx = index_from_grid_runs(
                points, normals, DEFAULT_CACHE_RESOLUTION, z["values"], z["lengths"]
            )
            _remember(idx, entry, spacing)
            return idx
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, IcpError) as e:
        _warn_once(f"ignoring unreadable index file {path} ({e})")
        return None


def store_index(
    m: Map, spacing: float, points: NDArray[Any], normals: NDArray[Any], index: MapIndex
) -> None:
    """Keep ``index``'s closest-point grid beside ``m``'s cache entry (see :func:`load_index`);
    nothing when ``m`` is not from the cache or the index has no default grid; a failure
    only warns (once)."""
    entry = getattr(m, _ENTRY, None)
    if entry is None:
        return
    _remember(index, entry, spacing)
    import numpy as np

    from icploc._core import DEFAULT_CACHE_RESOLUTION, grid_runs

    if index.cache_resolution != DEFAULT_CACHE_RESOLUTION:
        return
    got = grid_runs(index)
    if got is None:
        return
    values, lengths, res = got
    digest = np.frombuffer(_digest(points, normals), dtype=np.uint8)
    _write_atomic(
        _index_path(entry, spacing, res),
        lambda tmp: np.savez(
            tmp, values=values, lengths=lengths, resolution=np.float64(res), digest=digest
        ),
    )


def _remember(index: MapIndex, entry: Path, spacing: float) -> None:
    _INDEXES[id(index)] = (index, entry, spacing)
    while len(_INDEXES) > _MAX_INDEXES:
        del _INDEXES[next(iter(_INDEXES))]


def _field_path(entry: Path, spacing: float, resolution: float) -> Path:
    from icploc._core import FIELD_VERSION

    return entry.with_name(
        f"{entry.stem}.field-s{spacing!r}-r{resolution!r}-v{FIELD_VERSION}.npz"
    )


def global_localizer(index: MapIndex, resolution: float, **settings: Any) -> GlobalLocalizer:
    """``GlobalLocalizer(index, resolution, **settings)``; for the index of a map from (or
    into) the cache, its likelihood field's distances come from the file beside the entry
    when there is one for these points, and go there when not (a file that cannot be read
    or written warns once and the field is computed)."""
    from icploc._core import GlobalLocalizer

    known = _INDEXES.get(id(index))
    if known is None or known[0] is not index:
        return GlobalLocalizer(index, resolution, **settings)
    import zipfile

    import numpy as np

    from icploc._core import IcpError

    path = _field_path(known[1], known[2], resolution)
    digest = None
    if path.is_file():
        digest = _digest(index.points, index.normals)
        try:
            with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
                if z["digest"].tobytes() == digest:
                    return GlobalLocalizer(
                        index, resolution, distances=z["distances"], **settings
                    )
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, IcpError) as e:
            _warn_once(f"ignoring unreadable likelihood field file {path} ({e})")
    glob = GlobalLocalizer(index, resolution, **settings)
    mark = np.frombuffer(digest or _digest(index.points, index.normals), dtype=np.uint8)
    _write_atomic(path, lambda tmp: np.savez(tmp, distances=glob.distances(), digest=mark))
    return glob
