"""The flat YAML files map_server maps are, read without PyYAML (its import is ~15 ms of a
replay's start): :func:`plain_mapping`. Anything it is not sure of is None, for PyYAML to read.
This module imports nothing of icploc (the map reader and the output checks use it)."""

from __future__ import annotations

from typing import Any

_DIGITS = frozenset("0123456789")
_WORD_START = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_/")
_WORD_REST = _WORD_START | _DIGITS | frozenset(".-")
_SPECIAL = {"yes", "no", "true", "false", "on", "off", "null", "y", "n"}

# The tokens are matched by hand, not by regular expressions: compiling those is ~3 ms of
# a replay's start.


def _unsigned(text: str) -> str:
    return text[1:] if text[:1] in ("+", "-") and text else text


def _is_int(text: str) -> bool:
    """``[-+]?(0|[1-9][0-9]*)``"""
    s = _unsigned(text)
    return s != "" and all(c in _DIGITS for c in s) and (s == "0" or s[0] != "0")


def _is_float(text: str) -> bool:
    """``[-+]?[0-9]+\\.[0-9]*([eE][-+][0-9]+)?``"""
    s = _unsigned(text)
    n, i = len(s), 0
    while i < n and s[i] in _DIGITS:
        i += 1
    if i == 0 or i == n or s[i] != ".":
        return False
    i += 1
    while i < n and s[i] in _DIGITS:
        i += 1
    if i == n:
        return True
    if s[i] not in "eE" or n <= i + 2 or s[i + 1] not in "+-":
        return False
    return all(c in _DIGITS for c in s[i + 2 :])


def _is_number(text: str) -> bool:
    return _is_int(text) or _is_float(text)


def _is_word(text: str) -> bool:
    """A key or a plain word (``[A-Za-z_/][A-Za-z0-9_./-]*``): no YAML 1.1 bool / null
    word (checked apart), no number, no date."""
    return text != "" and text[0] in _WORD_START and all(c in _WORD_REST for c in text[1:])


def _scalar(text: str) -> Any:
    if _is_int(text):
        return int(text)
    if _is_float(text):
        return float(text)
    return text  # a word


def _value(rest: str) -> tuple[bool, str | None]:
    """What follows ``key:`` on a line: (well formed, the value's text or None for none).
    A value is one space or more, a number, a word or a flow list of numbers, then spaces,
    then perhaps `` #`` and a comment."""
    if rest == "":
        return True, None
    if rest[0] != " ":
        return False, None
    v = rest.lstrip(" ")
    if v.startswith("["):
        j = v.find("]")
        if j < 0 or not all(_is_number(x.strip(" ")) for x in v[1:j].split(",")):
            return False, None
        token, tail = v[: j + 1], v[j + 1 :]
    else:
        token, _sp, tail = v.partition(" ")
        tail = _sp + tail
        if not (_is_number(token) or _is_word(token)):
            return False, None
    after = tail.lstrip(" ")
    return (after == "" or (tail[:1] == " " and after[0] == "#")), token


def _item(line: str) -> tuple[str, str] | None:
    """A block list line ``( *)- +NUMBER``: (its indent, its number), or None."""
    s = line.lstrip(" ")
    if s[:2] != "- ":
        return None
    number = s[1:].lstrip(" ")
    return (line[: len(line) - len(s)], number) if _is_number(number) else None


def plain_mapping(text: str) -> dict[str, Any] | None:
    """``yaml.safe_load(text)`` for the flat files map_server maps are (``key: value``
    lines, values a plain word, a decimal number or a list of numbers, flow ``[a, b]`` or
    block ``- a`` lines, ``#`` comments), without importing PyYAML (~15 ms of a replay's
    start); None for anything else (nesting, quotes, duplicate keys, words YAML reads as
    bools, nulls, octal or sexagesimal numbers, ...), which PyYAML then reads.
    tests/test_maps_ros_plain.py checks the two agree."""
    out: dict[str, Any] = {}
    block: list[Any] | None = None  # the block list being read (its key's line had no value)
    indent = ""
    for line in text.split("\n"):
        line = line.rstrip(" \r")
        if not line or line.startswith("#"):
            continue
        if block is not None:
            item = _item(line)
            if item is not None and (not block or item[0] == indent):
                indent = item[0]
                block.append(_scalar(item[1]))
                continue
            if not block:
                return None  # a key without a value (null) or with a nested mapping
            block = None
        key, colon, rest = line.partition(":")
        ok, value = _value(rest)
        if not (colon and ok and _is_word(key)):
            return None
        if key in out or key.lower() in _SPECIAL:
            return None
        if value is None:
            block = out[key] = []
        elif value.lower() in _SPECIAL:
            return None
        elif value.startswith("["):
            out[key] = [_scalar(v.strip(" ")) for v in value[1:-1].split(",")]
        else:
            out[key] = _scalar(value)
    if block is not None and not block:
        return None
    return out if out else None
