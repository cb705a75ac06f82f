"""Suite-wide fixtures."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest


@pytest.fixture(autouse=True, scope="session")
def _private_map_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Every test writes prepared maps into a temporary cache, never the user's."""
    old = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg-cache"))
    yield
    if old is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = old


@pytest.fixture
def map_cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A map cache of this test's own, switched on (``ICPLOC_NO_CACHE`` unset) and with its
    once-per-process warning re-armed: the folder prepared maps and their grids go to."""
    from icploc.maps import cache

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("ICPLOC_NO_CACHE", raising=False)
    monkeypatch.setattr(cache, "_warned", False)
    return tmp_path / "xdg" / "icploc" / "maps"
