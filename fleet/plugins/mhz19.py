"""``mhz19``: a Winsen MH-Z19 (B/C/E) NDIR CO2 sensor on a serial line.

The sensor's UART protocol (9600 baud, 8N1): the host sends the nine bytes ``FF 01 86 00 00
00 00 00 79`` ("read CO2 concentration"); the sensor answers nine bytes ``FF 86 HH LL ..
.. .. .. CS``: the concentration is ``HH * 256 + LL`` ppm and ``CS`` the checksum of bytes 1
to 7 (their sum's two's complement, modulo 256). Options: ``port`` (the device, e.g.
``/dev/ttyS0``; required) and ``baud`` (9600).
"""

from __future__ import annotations

import time
from typing import Any

import serial

from fleet.driving import SensorFailure
from fleet.plugins import PluginError, SensorPlugin

READ_CO2 = bytes([0xFF, 0x01, 0x86, 0, 0, 0, 0, 0, 0x79])
FRAME = 9


def checksum(frame: bytes) -> int:
    """The MH-Z19 checksum of a nine-byte frame (over its bytes 1 to 7)."""
    return (0x100 - sum(frame[1:8])) & 0xFF


class MHZ19(SensorPlugin):
    kind = "scalar"

    @classmethod
    def check_options(cls, options: dict[str, Any]) -> None:
        extra = sorted(set(options) - {"port", "baud"})
        if extra:
            raise PluginError(f"mhz19 takes port and baud, not {', '.join(extra)}")
        port = options.get("port")
        if not isinstance(port, str) or not port:
            raise PluginError("mhz19 needs port: the serial device, e.g. /dev/ttyS0")
        baud = options.get("baud", 9600)
        if isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0:
            raise PluginError(f"mhz19's baud must be a positive whole number, not {baud!r}")

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self.port = str(options["port"])
        self._serial: Any = None
        self._baud = int(options.get("baud", 9600))

    def _line(self) -> Any:
        if self._serial is None:
            try:
                self._serial = serial.Serial(self.port, self._baud, timeout=0.1)
            except (OSError, ValueError, serial.SerialException) as exc:
                raise SensorFailure(
                    "the sensor's serial line cannot be opened",
                    where=f"mhz19 on {self.port}: {exc}",
                ) from exc
        return self._serial

    def read(self, timeout_s: float) -> dict[str, Any]:
        line = self._line()
        try:
            line.reset_input_buffer()
            line.write(READ_CO2)
            line.flush()
            answer = self._answer(line, time.monotonic() + timeout_s)
        except (OSError, serial.SerialException) as exc:
            self.close()  # opened again at the next reading
            raise SensorFailure(
                "the sensor's serial line failed", where=f"mhz19 on {self.port}: {exc}"
            ) from exc
        if answer is None:
            raise SensorFailure(f"no answer within {timeout_s:g} s", where=f"mhz19 on {self.port}")
        if checksum(answer) != answer[8]:
            raise SensorFailure(
                "an answer with a wrong checksum",
                where=f"mhz19 on {self.port} ({answer.hex(' ')})",
            )
        return {"value": float(answer[2] * 256 + answer[3])}

    def _answer(self, line: Any, deadline: float) -> bytes | None:
        """The sensor's answer frame (FF 86 ...), whatever came before it."""
        got = b""
        while time.monotonic() < deadline:
            got += bytes(line.read(FRAME))
            start = got.find(b"\xff\x86")
            if start >= 0 and len(got) - start >= FRAME:
                return got[start : start + FRAME]
        return None

    def close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            finally:
                self._serial = None
