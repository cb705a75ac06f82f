"""Checks on a serial port before a driver opens it, with messages a user can act on.

:func:`check_port` tells a missing device node, a file that is not a serial device,
missing permissions and a port that cannot be opened (busy, I/O error) apart, without
configuring the line. pyserial URLs (``socket://``, ``rfc2217://``, ``loop://`` ...)
are not device nodes and are passed through unchecked.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from icploc.errors import DeviceError

__all__ = ["PortError", "check_port", "is_url"]


class PortError(DeviceError, OSError):
    """A serial port is missing, not a serial device, not accessible, or busy."""


def is_url(port: str) -> bool:
    """True for a pyserial URL (``scheme://...``) rather than a device path."""
    return "://" in port


def check_port(port: str, role: str = "port") -> None:
    """Raise :class:`PortError` naming ``role`` (e.g. ``"laser (--laser)"``) and the port
    when ``port`` does not exist, is not a character device, cannot be read and written
    by this user, or cannot be opened right now."""
    if is_url(port):
        return
    p = Path(port)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise PortError(
            f"{role}: {port} does not exist (is the device plugged in? ls /dev/serial/by-id)"
        ) from None
    except OSError as e:
        raise PortError(f"{role}: {port}: {e.strerror or e}") from None
    if not stat.S_ISCHR(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a serial device"
        raise PortError(f"{role}: {port} is {kind}")
    if not os.access(p, os.R_OK | os.W_OK):
        raise PortError(
            f"{role}: permission denied on {port} (needs read and write access; "
            "on most systems: add the user to the 'dialout' group)"
        )
    try:
        fd = os.open(p, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as e:
        why = {
            errno.EACCES: "permission denied",
            errno.EBUSY: "busy (another program has it open)",
            errno.ENXIO: "no device behind the device node",
            errno.ENODEV: "no device behind the device node",
            errno.EIO: "I/O error (device unplugged?)",
        }.get(e.errno or 0, e.strerror or str(e))
        raise PortError(f"{role}: cannot open {port}: {why}") from None
    os.close(fd)
