"""The simulated vehicle's end of the link: the pymavlink connection, a sender for each of its
components, the loop that reads it, and the test hooks that break it (a cut link, lost
messages)."""

from __future__ import annotations

import contextlib
import logging
import threading
from collections import defaultdict
from collections.abc import Callable, Iterable
from typing import Any

from fleet.mavlink.endpoint import Endpoint
from fleet.mavlink.errors import LinkError
from fleet.mavlink.wire import BAD_DATA, connect, drop_closed_tcp_client, mavlink

logger = logging.getLogger("cpcc.mavsim")

# What is sent: a function that sends one message with pymavlink's MAVLink object.
Build = Callable[[Any], None]


def reply_to(msg: Any) -> tuple[int, int]:
    """The system and component a message came from."""
    return int(msg.get_srcSystem()), int(msg.get_srcComponent())


class Transport:
    """The connection to ``endpoint`` as system ``system_id``: ``send`` sends from
    ``component_id`` (the autopilot), ``sender`` gives the send of one of the other
    ``components`` (each with its own sequence numbers). ``name`` goes into the log."""

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        system_id: int,
        component_id: int,
        components: Iterable[int],
        name: str,
    ) -> None:
        self.endpoint = endpoint
        self._system_id = system_id
        self._component_id = component_id
        self._components = tuple(components)
        self._name = name
        self._conn: Any = None
        self._component_mavs: dict[int, Any] = {}
        self.cut = False  # silent and deaf, as if the radio died
        self._drops: dict[str, int] = defaultdict(int)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def open(self) -> None:
        """Raises LinkError when the connection cannot be opened (a port in use, no
        pyserial)."""
        try:
            self._conn = connect(
                self.endpoint.pymavlink_device,
                baud=self.endpoint.baud,
                source_system=self._system_id,
                source_component=self._component_id,
            )
        except ImportError as exc:
            raise LinkError(f"{self.endpoint}: serial links need pyserial ({exc})") from exc
        except (OSError, ValueError) as exc:
            raise LinkError(f"mavsim cannot open {self.endpoint}: {exc}") from exc
        self._component_mavs = {
            component: mavlink.MAVLink(self._conn, self._system_id, component)
            for component in self._components
        }

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._component_mavs = {}
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def start(self, step: Callable[[Any | None], None]) -> None:
        """``serve`` in a background thread until ``stop``."""
        self._stop.clear()
        self._thread = threading.Thread(
            target=self.serve, args=(self._stop, step), name=f"mavsim {self._name}", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop the loop and wait for its thread (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._thread = None

    def serve(self, stop: threading.Event, step: Callable[[Any | None], None]) -> None:
        """Read until ``stop`` is set (or ``stop()`` is called), calling ``step`` with each
        message received, and with None when none came within a hundredth of a second."""
        self._stop = stop
        conn = self._conn
        while not stop.is_set():
            try:
                # A short wait keeps the message rates (up to 100 Hz) and the flight's
                # events (take-off done, touchdown) within a hundredth of a second.
                msg = conn.recv_match(blocking=True, timeout=0.01)
                if msg is None:
                    drop_closed_tcp_client(conn)
                step(msg)
            except Exception:
                if stop.is_set():
                    return
                logger.exception("mavsim %s", self._name)
                stop.wait(0.2)

    def accepts(self, msg: Any) -> bool:
        """Whether a received message is for this vehicle and gets through (not garbage, not
        lost to a cut link or a drop)."""
        kind = msg.get_type()
        if kind == BAD_DATA or self.cut:
            return False
        if self._drops.get(kind, 0) > 0:
            self._drops[kind] -= 1
            return False
        # Not addressed to another vehicle.
        return getattr(msg, "target_system", 0) in (0, self._system_id)

    def drop(self, msg_type: str, count: int) -> None:
        """Lose the next ``count`` received messages of a type."""
        self._drops[msg_type] += count

    def send(self, build: Build) -> None:
        """Send from the autopilot."""
        if self.cut or self._conn is None:
            return
        build(self._conn.mav)

    def sender(self, component: int) -> Callable[[Build], None]:
        """The send of another component of the vehicle."""

        def send(build: Build) -> None:
            mav = self._component_mavs.get(component)
            if self.cut or mav is None:
                return
            build(mav)

        return send
