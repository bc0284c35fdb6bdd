"""Telemetry logs (``.tlog``): a flight's MAVLink messages as ground-station tools read them.

A ``.tlog`` is what Mission Planner, QGroundControl, MAVProxy and pymavlink write and read: per
message, an 8-byte big-endian unsigned timestamp (microseconds since the Unix epoch) followed by
the message's bytes as they went over the wire. pymavlink's reader (``mavutil.mavlogfile``,
what ``mavutil.mavlink_connection("x.tlog")`` and ``mavlogdump.py`` open) takes the two low
bits of the timestamp as the link the message came on, so a writer clears them (pymavlink's
own ``setup_logfile`` does the same): we log one link.

- ``tlog_entry`` frames one message; ``TlogRecorder`` collects a flight's messages as the
  MAVLink link receives (and sends) them, spooled to a temporary file with a size cap;
- ``simulated_tlog`` (``fleet.mavlink.tlog_sim``) makes the log a simulated RV's flight would
  have had, from its track.

No Django here: the worker stores the bytes (``vvm_worker.services.flight_logs``).
"""

from __future__ import annotations

import logging
import struct
import tempfile
import threading
import time
from collections.abc import Callable
from typing import IO

logger = logging.getLogger("cpcc.mavlink.tlog")

__all__ = ["TLOG_MAX_BYTES", "TlogRecorder", "tlog_entry"]

# A flight's log is cut here (the messages after it are dropped and counted): at the rates the
# driver asks for (GLOBAL_POSITION_INT at 4 Hz, a dozen others at 1 Hz, our setpoints and
# heartbeats) a log grows by about 1.5 kB a second, so 64 MB is over ten hours of flight, and a
# link that floods the worker cannot fill its disk.
TLOG_MAX_BYTES = 64 * 1024 * 1024
_TIMESTAMP = struct.Struct(">Q")
_LINK_BITS = 3  # the timestamp's two low bits: the link number (0 here)


def tlog_entry(time_s: float, message: bytes) -> bytes:
    """One ``.tlog`` record: ``message`` (a MAVLink frame's bytes) at ``time_s`` (Unix epoch
    seconds). Raises ValueError for a time before the epoch."""
    usec = int(time_s * 1e6)
    if usec < 0:
        raise ValueError(f"a .tlog timestamp cannot be before 1970 (got {time_s!r})")
    return _TIMESTAMP.pack(usec & ~_LINK_BITS) + message


class TlogRecorder:
    """One vehicle's flight log in the making: the MAVLink link hands it every message
    (``record``, on its reader thread, and on any thread that sends), and the worker brackets
    a flight with ``start`` and ``finish``. Between flights ``record`` does nothing.

    Messages are spooled to an anonymous temporary file (not memory), at most ``max_bytes``
    of them a flight; later ones are dropped and counted (``dropped``), and the cut is logged
    once. ``clock``: the timestamp of each message as it comes, Unix epoch seconds (the wall
    clock, as a ground station logs).
    """

    def __init__(
        self,
        *,
        max_bytes: int = TLOG_MAX_BYTES,
        clock: Callable[[], float] = time.time,
        name: str = "",
    ) -> None:
        if max_bytes <= 0:
            raise ValueError("max_bytes must be > 0")
        self.max_bytes = max_bytes
        self.clock = clock
        self.name = name
        self.dropped = 0
        self._file: IO[bytes] | None = None
        self._size = 0
        self._lock = threading.Lock()  # the reader thread, senders and the worker's thread

    @property
    def recording(self) -> bool:
        """Whether a flight is being recorded (between ``start`` and ``finish``)."""
        return self._file is not None

    @property
    def size(self) -> int:
        """Bytes recorded this flight so far."""
        return self._size

    def start(self) -> None:
        """Begin a flight's log; a log still open (a flight never finished) is discarded."""
        # Open until ``finish`` hands it over: the flight outlives this call.
        spool = tempfile.TemporaryFile(prefix="cpcc-flight-", suffix=".tlog")  # noqa: SIM115
        with self._lock:
            previous, self._file = self._file, spool
            self._size = 0
            self.dropped = 0
        if previous is not None:
            previous.close()

    def record(self, message: bytes) -> None:
        """Add a message's bytes (``msg.get_msgbuf()``) stamped now; nothing between flights.

        On the link's hot path: one clock read and one buffered write under a lock.
        """
        if self._file is None:
            return
        entry = tlog_entry(self.clock(), message)
        with self._lock:
            spool = self._file
            if spool is None:
                return
            if self._size + len(entry) > self.max_bytes:
                if not self.dropped:
                    logger.warning(
                        "%s: flight log full at %d bytes: later messages are dropped",
                        self.name,
                        self._size,
                    )
                self.dropped += 1
                return
            spool.write(entry)
            self._size += len(entry)

    def finish(self) -> IO[bytes] | None:
        """End the flight's log and return it: an open binary file, read from its start, that
        disappears when closed (close it once stored). None when no flight was being recorded.
        """
        with self._lock:
            spool, self._file = self._file, None
        if spool is None:
            return None
        spool.flush()
        spool.seek(0)
        return spool

    def discard(self) -> None:
        """Drop the flight's log, if any (the worker stops, the vehicle is released)."""
        spool = self.finish()
        if spool is not None:
            spool.close()
