"""Connection strings: where a MAVLink link goes.

=============================  ====================================================================
``udpin:HOST:PORT``            listen on a UDP port; answers go to whoever sent (``udp:`` is the
                               same, as in pymavlink and MAVProxy). A companion computer's usual
                               ``udpin:0.0.0.0:14550``, or ``mavsim``'s side of a test link.
``udpout:HOST:PORT``           send to HOST:PORT (the other side listens), e.g. to ArduPilot SITL
                               or a ``mavsim --connection udpin:...``.
``tcp:HOST:PORT``              connect to a TCP server (SITL's ``tcp:127.0.0.1:5760``);
                               reconnects when the server drops the connection.
``tcpin:HOST:PORT``            accept one TCP client at a time.
``serial:DEVICE[:BAUD]``       a serial port, e.g. ``serial:/dev/ttyUSB0:921600``
``DEVICE[,BAUD]``              the same in MAVProxy's spelling, e.g. ``/dev/ttyACM0,57600``;
                               DEVICE must start with ``/`` (or be ``COMn``). BAUD defaults to
                               57600, a telemetry radio's rate.
=============================  ====================================================================

Serial ports need the ``pyserial`` package, which pymavlink imports only for serial links.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from fleet.mavlink.errors import LinkError

DEFAULT_BAUD = 57600
_NETWORK_SCHEMES = {
    "udpin": "udpin",
    "udp": "udpin",
    "udpout": "udpout",
    "tcp": "tcp",
    "tcpin": "tcpin",
}
_WINDOWS_PORT = re.compile(r"^COM\d+$", re.IGNORECASE)


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string.

    ``scheme`` is "udpin", "udpout", "tcp", "tcpin" or "serial"; network endpoints have
    ``host`` and ``port``, serial ones ``device`` and ``baud``.
    """

    scheme: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = DEFAULT_BAUD

    @property
    def pymavlink_device(self) -> str:
        """The device string ``mavutil.mavlink_connection`` takes."""
        if self.scheme == "serial":
            return self.device
        return f"{self.scheme}:{self.host}:{self.port}"

    def __str__(self) -> str:
        if self.scheme == "serial":
            return f"serial:{self.device}:{self.baud}"
        return f"{self.scheme}:{self.host}:{self.port}"


def parse_endpoint(text: str) -> Endpoint:
    """Parse a connection string (see the module's table).

    Returns the Endpoint. Raises LinkError (permanent) naming what is wrong: an unknown scheme,
    a missing or non-numeric port or baud rate.
    """
    text = text.strip()
    if not text:
        raise LinkError("empty MAVLink connection string")
    if text.startswith("serial:"):
        return _serial(text.removeprefix("serial:"), ":", text)
    if text.startswith("/") or _WINDOWS_PORT.match(text.split(",", 1)[0]):
        return _serial(text, ",", text)
    scheme, sep, rest = text.partition(":")
    if not sep or scheme not in _NETWORK_SCHEMES:
        raise LinkError(
            f"unknown MAVLink connection {text!r}: use udpin:HOST:PORT, udpout:HOST:PORT, "
            "tcp:HOST:PORT, tcpin:HOST:PORT, serial:DEVICE:BAUD or DEVICE,BAUD"
        )
    host, sep, port = rest.rpartition(":")
    if not sep or not host:
        raise LinkError(f"{text!r}: expected {scheme}:HOST:PORT")
    return Endpoint(_NETWORK_SCHEMES[scheme], host=host, port=_number(port, "port", text, 65535))


def _serial(rest: str, separator: str, text: str) -> Endpoint:
    device, sep, baud = rest.rpartition(separator)
    if not sep or not baud.isdigit():
        # No baud rate given (or the separator belongs to the device name).
        device, baud = rest, ""
    if not device:
        raise LinkError(f"{text!r}: no serial device")
    rate = _number(baud, "baud rate", text, 10_000_000) if baud else DEFAULT_BAUD
    return Endpoint("serial", device=device, baud=rate)


def _number(value: str, what: str, text: str, maximum: int) -> int:
    if not value.isdigit() or not 0 < int(value) <= maximum:
        raise LinkError(f"{text!r}: {what} must be a number from 1 to {maximum}, got {value!r}")
    return int(value)


_MIRRORS = {"udpout": "udpin", "udpin": "udpout", "tcp": "tcpin", "tcpin": "tcp"}


def mirror_endpoint(text: str) -> str:
    """The other end of a network link: what a simulator listens on when a driver connects
    with ``text`` (``udpout:H:P`` gives ``udpin:H:P``, ``tcp:H:P`` gives ``tcpin:H:P``, and
    back). Raises LinkError for a serial link, which has no other end here."""
    endpoint = parse_endpoint(text)
    if endpoint.scheme == "serial":
        raise LinkError(f"{text!r} is a serial port: give the simulator its own connection")
    return f"{_MIRRORS[endpoint.scheme]}:{endpoint.host}:{endpoint.port}"
