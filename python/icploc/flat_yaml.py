"""The flat YAML files map_server maps are, read without PyYAML (its import is ~15 ms of a
replay's start): :func:`plain_mapping`. Anything it is not sure of is None, for PyYAML to read.
This module imports nothing of icploc (the map reader and the output checks use it)."""

from __future__ import annotations

from typing import Any

_INT = r"[-+]?(?:0|[1-9][0-9]*)"
_FLOAT = r"[-+]?[0-9]+\.[0-9]*(?:[eE][-+][0-9]+)?"
_NUMBER = rf"(?:{_FLOAT}|{_INT})"
#: a key or a plain word: no YAML 1.1 bool / null word (checked apart), no number, no date
_WORD = r"[A-Za-z_/][A-Za-z0-9_./-]*"
_SPECIAL = {"yes", "no", "true", "false", "on", "off", "null", "y", "n"}
_LINE: Any = None
_ITEM: Any = None


def _scalar(text: str) -> Any:
    import re

    if re.fullmatch(_INT, text):
        return int(text)
    if re.fullmatch(_FLOAT, text):
        return float(text)
    return text  # a _WORD


def plain_mapping(text: str) -> dict[str, Any] | None:
    """``yaml.safe_load(text)`` for the flat files map_server maps are (``key: value``
    lines, values a plain word, a decimal number or a list of numbers, flow ``[a, b]`` or
    block ``- a`` lines, ``#`` comments), without importing PyYAML (~15 ms of a replay's
    start); None for anything else (nesting, quotes, duplicate keys, words YAML reads as
    bools, nulls, octal or sexagesimal numbers, ...), which PyYAML then reads.
    tests/test_maps_ros_plain.py checks the two agree."""
    import re

    global _LINE, _ITEM
    if _LINE is None:
        value = rf"(?:{_NUMBER}|{_WORD}|\[ *{_NUMBER}(?: *, *{_NUMBER})* *\])"
        _LINE = re.compile(rf"({_WORD}):(?: +({value}) *(?: #.*)?)?")
        _ITEM = re.compile(rf"( *)- +({_NUMBER})")
    out: dict[str, Any] = {}
    block: list[Any] | None = None  # the block list being read (its key's line had no value)
    indent = ""
    for line in text.split("\n"):
        line = line.rstrip(" \r")
        if not line or line.startswith("#"):
            continue
        if block is not None:
            item = _ITEM.fullmatch(line)
            if item is not None and (not block or item.group(1) == indent):
                indent = item.group(1)
                block.append(_scalar(item.group(2)))
                continue
            if not block:
                return None  # a key without a value (null) or with a nested mapping
            block = None
        m = _LINE.fullmatch(line)
        if m is None:
            return None
        key, value = m.group(1), m.group(2)
        if key in out or key.lower() in _SPECIAL:
            return None
        if value is None:
            block = out[key] = []
        elif value.lower() in _SPECIAL:
            return None
        elif value.startswith("["):
            out[key] = [_scalar(v.strip()) for v in value[1:-1].split(",")]
        else:
            out[key] = _scalar(value)
    if block is not None and not block:
        return None
    return out if out else None
