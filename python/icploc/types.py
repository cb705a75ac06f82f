"""Deprecated: the sensor messages moved to :mod:`icploc.messages`.

``icploc.types`` stays importable for existing code and re-exports the same objects
(``icploc.types.Scan is icploc.messages.Scan``). New code imports :mod:`icploc.messages`;
nothing inside the package imports this module (tests/test_layers.py checks).
"""

from __future__ import annotations

from icploc.messages import (
    BEAM_DAZZLE,
    BEAM_FIELD_A,
    BEAM_FIELD_B,
    BEAM_FIELD_C,
    BEAM_INVALID,
    BEAM_NO_RETURN,
    Odometry,
    Scan,
)

__all__ = [
    "BEAM_DAZZLE",
    "BEAM_FIELD_A",
    "BEAM_FIELD_B",
    "BEAM_FIELD_C",
    "BEAM_INVALID",
    "BEAM_NO_RETURN",
    "Odometry",
    "Scan",
]
