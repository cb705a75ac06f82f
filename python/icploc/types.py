"""Deprecated: the sensor messages moved to :mod:`icploc.messages`.

``icploc.types`` stays importable for existing code and re-exports the same objects
(``icploc.types.Scan is icploc.messages.Scan``). New code imports :mod:`icploc.messages`;
nothing inside the package imports this module (tests/test_layers.py checks).
"""

from __future__ import annotations

from icploc import messages as _messages
from icploc.messages import *  # noqa: F403

__all__ = list(_messages.__all__)
