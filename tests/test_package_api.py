"""What ``import icploc`` offers: the error root, the messages and the main API, loaded lazily."""

from __future__ import annotations

import importlib
import subprocess
import sys

import icploc
import icploc.errors
import icploc.messages
import icploc.types
import pytest

ERRORS = ("IcplocError", "FileFormatError", "ConfigError", "DeviceError", "UsageError")


@pytest.mark.parametrize("name", ERRORS)
def test_the_root_re_exports_the_error_root(name: str) -> None:
    assert getattr(icploc, name) is getattr(icploc.errors, name)


@pytest.mark.parametrize("name", sorted(icploc._LAZY))
def test_every_lazy_name_is_the_object_of_its_module(name: str) -> None:
    module, attr = icploc._LAZY[name]
    assert getattr(icploc, name) is getattr(importlib.import_module(module), attr)


def test_every_name_in_all_resolves() -> None:
    missing = [n for n in icploc.__all__ if not hasattr(icploc, n)]
    assert missing == []


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'nonesuch'"):
        icploc.nonesuch  # noqa: B018


def test_the_types_alias_holds_the_same_messages() -> None:
    assert (icploc.types.Scan, icploc.types.Odometry, icploc.types.BEAM_NO_RETURN) == (
        icploc.messages.Scan,
        icploc.messages.Odometry,
        icploc.messages.BEAM_NO_RETURN,
    )


def test_import_icploc_loads_no_localization_or_settings() -> None:
    code = (
        "import sys, icploc\n"
        "heavy = ('icploc.localizer', 'icploc.maps', 'icploc.config', 'icploc.logs',"
        " 'icploc.trajectory', 'pydantic', 'scipy', 'matplotlib')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
