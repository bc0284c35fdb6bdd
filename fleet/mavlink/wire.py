"""pymavlink, loaded for MAVLink 2 with the ardupilotmega dialect (which includes common.xml).

pymavlink picks its wire protocol once, from the ``MAVLINK20`` environment variable, when it
loads a dialect; without it every connection speaks MAVLink 1 until it happens to receive a
MAVLink 2 frame first. MAVLink 1 cannot carry extension fields, and the mission protocol's
``mission_type`` is one: a fence upload over MAVLink 1 would silently become a mission upload.
So this module sets the variable before the dialect is loaded (or loads it again if someone
imported pymavlink earlier), and everything in ``fleet.mavlink`` imports pymavlink from here.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # must come after MAVLINK20 is set

mavutil.set_dialect("ardupilotmega")

# The generated dialect module: message classes, constants (MAV_CMD_*, MAV_RESULT_*, ...).
mavlink: Any = mavutil.mavlink

# pymavlink's parser returns this type for bytes it could not decode.
BAD_DATA = "BAD_DATA"


def connect(device: str, *, baud: int, source_system: int, source_component: int) -> Any:
    """Open a pymavlink connection (``mavutil.mavlink_connection``) speaking MAVLink 2.

    ``device`` is a pymavlink device string (see ``fleet.mavlink.endpoint``). Raises OSError
    (socket or serial errors) or ValueError (a malformed address) as pymavlink does.
    """
    return mavutil.mavlink_connection(
        device,
        baud=baud,
        source_system=source_system,
        source_component=source_component,
        dialect="ardupilotmega",
        autoreconnect=device.startswith("tcp:"),
        # One connection attempt, no sleeping between retries: a vehicle that is not there
        # yet is the link-loss logic's business, not the constructor's.
        retries=0,
    )


def encode_text(text: str, size: int) -> bytes:
    """A char[size] field's bytes: UTF-8, cut to ``size`` bytes (no terminator needed)."""
    return text.encode("utf-8")[:size]


def drop_closed_tcp_client(conn: Any) -> None:
    """Let a ``tcpin:`` connection accept a new client after the current one hung up.

    pymavlink's mavtcpin reads an empty string at end-of-file without closing the socket,
    so the closed socket stays "readable" forever and the receive loop spins. Peek: if the
    client is gone, close its socket and go back to listening.
    """
    port = getattr(conn, "port", None)
    listen = getattr(conn, "listen", None)
    if port is None or listen is None:
        return
    try:
        readable, _, _ = select.select([port], [], [], 0)
        if not readable or port.recv(1, socket.MSG_PEEK) != b"":
            return
    except OSError:
        pass
    with contextlib.suppress(OSError):
        port.close()
    conn.port = None
    conn.fd = listen.fileno()
