"""A MAVLink link to one vehicle over pymavlink: heartbeats, commands, parameters, missions.

``MavlinkLink`` opens a connection (``fleet.mavlink.endpoint`` lists the connection strings),
and runs two threads of its own:

- the *reader* receives every message, locks onto the first vehicle heartbeat (an autopilot's,
  not a GCS's or a gimbal's) unless a target system is given, keeps the latest message of each
  type, assembles STATUSTEXT chunks, and hands messages to waiting requests and listeners;
- the *timer* sends our HEARTBEAT (a GCS or an onboard controller) at 1 Hz, which is also what
  tells a UDP vehicle where to send, and declares the link lost when the vehicle's heartbeat
  has not been heard for ``link_timeout_s`` (and regained when it comes back), with callbacks.

Requests are synchronous for the caller and bounded in time: a command is re-sent (COMMAND_LONG
with ``confirmation`` counting the attempts) until a COMMAND_ACK comes or the attempts run out;
parameter reads and writes wait for the matching PARAM_VALUE; a mission upload follows the
mission protocol's request/item exchange with timeouts. Every failure is a typed
``fleet.mavlink.errors`` error that says whether it is permanent.

A ``recorder`` (``fleet.mavlink.tlog.TlogRecorder``), when set, gets the bytes of every message
the reader receives and, with ``record_sent``, of every message sent: a flight's ``.tlog``.

Listener callbacks and the link-loss callbacks run on the link's threads: keep them short, and
never call a blocking request (a command) from them.

This module is the transport (connection, threads, heartbeats, dispatch to waiters and
listeners); each sub-protocol is a part of ``MavlinkLink`` in a module of its own:
``commanding`` (commands, rates, modes, arming), ``parameters``, ``mission_transfer``
(missions, the fence, rally points), over what ``exchange.LinkCore`` says they share.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

from fleet.mavlink.commanding import Commanding
from fleet.mavlink.endpoint import parse_endpoint
from fleet.mavlink.errors import (
    LinkError,
    LinkLost,
)
from fleet.mavlink.exchange import CommandAck, Heartbeat, StatusText, Waiter
from fleet.mavlink.mission_transfer import MissionTransfer
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.parameters import Parameters
from fleet.mavlink.tlog import TlogRecorder
from fleet.mavlink.wire import BAD_DATA, connect, drop_closed_tcp_client, mavlink

logger = logging.getLogger("cpcc.mavlink")

__all__ = ["CommandAck", "Heartbeat", "MavlinkLink", "StatusText"]

# Heartbeats of these types come from ground stations, companions and accessories, never from
# the vehicle's autopilot (pymavlink's probably_vehicle_heartbeat uses the same list).
_NOT_A_VEHICLE = frozenset(
    {
        mavlink.MAV_TYPE_GCS,
        mavlink.MAV_TYPE_GIMBAL,
        mavlink.MAV_TYPE_ADSB,
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
    }
)
_STATUSTEXT_CHUNK = 50  # STATUSTEXT.text is char[50]; a longer text is sent in chunks


class MavlinkLink(Commanding, Parameters, MissionTransfer):
    """A link to one vehicle. See the module docstring for what it does.

    ``connection``: a connection string (``fleet.mavlink.endpoint``). ``source_system`` and
    ``source_component``: our ids (255/190 is a ground station as ArduPilot's SYSID_MYGCS
    expects; a companion computer uses the vehicle's system id and 191). ``mav_type``: the
    type in our heartbeat (MAV_TYPE_GCS or MAV_TYPE_ONBOARD_CONTROLLER). ``target_system``:
    the vehicle's system id, or None to take the first vehicle heard. ``link_timeout_s``:
    silence after which the link counts as lost. ``command_timeout_s`` and
    ``command_attempts``: how long to wait for each answer and how often to send a request.
    ``monotonic``: the clock for all of these (injectable for tests).
    """

    def __init__(
        self,
        connection: str,
        *,
        source_system: int = 255,
        source_component: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
        mav_type: int = mavlink.MAV_TYPE_GCS,
        target_system: int | None = None,
        target_component: int = mavlink.MAV_COMP_ID_AUTOPILOT1,
        heartbeat_hz: float = 1.0,
        link_timeout_s: float = 3.0,
        command_timeout_s: float = 1.0,
        command_attempts: int = 3,
        monotonic: Callable[[], float] = time.monotonic,
        on_link_lost: Callable[[], None] | None = None,
        on_link_regained: Callable[[], None] | None = None,
    ) -> None:
        if heartbeat_hz <= 0 or link_timeout_s <= 0 or command_timeout_s <= 0:
            raise ValueError("heartbeat_hz, link_timeout_s and command_timeout_s must be > 0")
        if command_attempts < 1:
            raise ValueError("command_attempts must be at least 1")
        self.endpoint = parse_endpoint(connection)
        self.source_system = source_system
        self.source_component = source_component
        self.mav_type = mav_type
        self.target_system = target_system
        self.target_component = target_component
        self.heartbeat_period_s = 1.0 / heartbeat_hz
        self.link_timeout_s = link_timeout_s
        self.command_timeout_s = command_timeout_s
        self.command_attempts = command_attempts
        self.monotonic = monotonic
        self.on_link_lost = on_link_lost
        self.on_link_regained = on_link_regained

        self._conn: Any = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()  # state below, shared by the reader, timer and callers
        self._send_lock = threading.Lock()  # pymavlink's encoder is not thread-safe
        self._command_lock = threading.Lock()  # one command in flight (see command_long)
        self._mission_lock = threading.Lock()  # one mission transfer at a time
        self._heartbeat: Heartbeat | None = None
        self._heard = threading.Event()
        self._link_ok = False
        self._latest: dict[str, Any] = {}
        self._texts: deque[StatusText] = deque(maxlen=200)
        self._chunks: dict[int, list[str]] = {}
        self._waiters: list[Waiter] = []
        self._listeners: dict[str, list[Callable[[Any], None]]] = {}
        self._param_types: dict[str, int] = {}
        # The flight log (``fleet.mavlink.tlog``): every message heard, and with ``record_sent``
        # every message sent, as a ground station's .tlog has both directions.
        self.recorder: TlogRecorder | None = None
        self.record_sent = True

    # --- life cycle -----------------------------------------------------------------------

    def open(self) -> MavlinkLink:
        """Open the connection and start the reader and timer threads; returns self.

        Raises LinkError when the connection cannot be opened: permanent for a port in use, a
        missing serial device or no pyserial for a serial link; not for a TCP server that
        refuses the connection (it may not be up yet).
        """
        if self._conn is not None:
            return self
        try:
            self._conn = connect(
                self.endpoint.pymavlink_device,
                baud=self.endpoint.baud,
                source_system=self.source_system,
                source_component=self.source_component,
            )
        except ImportError as exc:
            raise LinkError(f"{self.endpoint}: serial links need pyserial ({exc})") from exc
        except ConnectionError as exc:
            # A TCP server that is not up yet (SITL starting, a router restarting) may be
            # there later.
            raise LinkError(f"cannot connect to {self.endpoint}: {exc}", permanent=False) from exc
        except (OSError, ValueError) as exc:
            raise LinkError(f"cannot open MAVLink connection {self.endpoint}: {exc}") from exc
        self._conn.mav.set_send_callback(self._on_sent)
        self._stop.clear()
        for name, target in (("reader", self._read_loop), ("timer", self._timer_loop)):
            thread = threading.Thread(
                target=target, name=f"mavlink-{name} {self.endpoint}", daemon=True
            )
            thread.start()
            self._threads.append(thread)
        return self

    def close(self) -> None:
        """Stop the threads and close the connection (idempotent)."""
        self._stop.set()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._threads.clear()
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def __enter__(self) -> MavlinkLink:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- state ----------------------------------------------------------------------------

    @property
    def heartbeat(self) -> Heartbeat | None:
        """The vehicle's last heartbeat, or None before the first."""
        return self._heartbeat

    @property
    def autopilot(self) -> Autopilot:
        """ArduPilot, PX4 or other, from the heartbeat (OTHER before the first)."""
        beat = self._heartbeat
        return beat.autopilot if beat is not None else Autopilot.OTHER

    @property
    def link_ok(self) -> bool:
        """True while the vehicle's heartbeat is fresh (False before the first)."""
        return self._link_ok

    def wait_heartbeat(self, timeout_s: float) -> Heartbeat:
        """Block until the vehicle has been heard; returns its heartbeat.

        Raises LinkLost (not permanent) when nothing is heard within ``timeout_s``.
        """
        if not self._heard.wait(timeout_s) or self._heartbeat is None:
            raise LinkLost(f"no heartbeat from a vehicle on {self.endpoint} within {timeout_s:g} s")
        return self._heartbeat

    def last_message(self, msg_type: str) -> Any | None:
        """The vehicle's latest message of a type (e.g. "GLOBAL_POSITION_INT"), or None."""
        return self._latest.get(msg_type)

    def status_texts(self, since: float = -math.inf) -> list[StatusText]:
        """STATUSTEXT lines received after ``since`` (the link's monotonic clock), oldest first."""
        with self._lock:
            return [t for t in self._texts if t.received > since]

    def next_message(
        self, match: Callable[[Any], bool], timeout_s: float, *, any_component: bool = False
    ) -> Any | None:
        """The vehicle's next message that ``match`` accepts, received from now on within
        ``timeout_s`` (``any_component``: from any of the vehicle's components, e.g. a
        companion computer's NAMED_VALUE_FLOAT; else the autopilot's only); None if none."""
        with self.waiting(match, any_component=any_component) as waiter:
            return waiter.get(timeout_s)

    def add_listener(self, msg_type: str, callback: Callable[[Any], None]) -> Callable[[], None]:
        """Call ``callback(msg)`` on the reader thread for each such message from the vehicle.

        Returns a function that removes the listener. Exceptions in callbacks are logged.
        """
        with self._lock:
            self._listeners.setdefault(msg_type, []).append(callback)

        def remove() -> None:
            with self._lock:
                callbacks = self._listeners.get(msg_type, [])
                if callback in callbacks:
                    callbacks.remove(callback)

        return remove

    def send(self, build: Callable[[Any], None]) -> None:
        """Send a message: ``build`` gets pymavlink's MAVLink object and calls one ``*_send``.

        Example: ``link.send(lambda mav: mav.statustext_send(6, b"hello"))``.
        Raises LinkError if the link is not open.
        """
        conn = self._conn
        if conn is None:
            raise LinkError("the MAVLink link is not open")
        with self._send_lock:
            build(conn.mav)

    # --- internals ------------------------------------------------------------------------

    def _target(self) -> int:
        return self.target_system if self.target_system is not None else 0

    def _require_link(self) -> Heartbeat:
        beat = self._heartbeat
        if beat is None or not self._link_ok:
            raise LinkLost(f"the link to the vehicle on {self.endpoint} is down")
        return beat

    @contextlib.contextmanager
    def waiting(
        self, match: Callable[[Any], bool], *, any_component: bool = False
    ) -> Iterator[Waiter]:
        """Collect the vehicle's messages that ``match`` accepts for the block's duration
        (``get(timeout_s)`` takes the next): registered before the block sends what they
        answer, so no answer is lost. ``any_component``: from any of its components."""
        waiter = Waiter(match, any_component=any_component)
        with self._lock:
            self._waiters.append(waiter)
        try:
            yield waiter
        finally:
            with self._lock:
                self._waiters.remove(waiter)

    def _read_loop(self) -> None:
        failing = False
        while not self._stop.is_set():
            conn = self._conn
            if conn is None:
                return
            try:
                msg = conn.recv_match(blocking=True, timeout=0.1)
                if msg is None:
                    drop_closed_tcp_client(conn)
                    continue
                failing = False
                self._dispatch(msg)
            except Exception as exc:
                if self._stop.is_set():
                    return
                # A socket error, a TCP server that went away (pymavlink reconnects on the
                # next read), a malformed frame: the link-loss logic reports the consequences;
                # here we only avoid spinning, and logging the same failure twice a second.
                if not failing:
                    logger.warning("MAVLink reader on %s: %r", self.endpoint, exc, exc_info=True)
                failing = True
                self._stop.wait(0.5)

    def _on_sent(self, msg: Any) -> None:
        recorder = self.recorder
        if recorder is not None and self.record_sent:
            recorder.record(msg.get_msgbuf())

    def _dispatch(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == BAD_DATA:
            return
        recorder = self.recorder
        if recorder is not None:
            recorder.record(msg.get_msgbuf())
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        now = self.monotonic()
        if kind == "HEARTBEAT" and self._is_vehicle_heartbeat(msg, source):
            self._on_heartbeat(msg, source, now)
        if self.target_system is None or source[0] != self.target_system:
            return
        if kind == "STATUSTEXT":
            self._on_statustext(msg, now)
        autopilot = source[1] == self.target_component
        if autopilot and kind == "PARAM_VALUE":
            self._param_types[msg.param_id] = int(msg.param_type)
        with self._lock:
            # Another component of the vehicle (a companion computer, a camera, a gimbal)
            # reaches only the waiters that ask for it.
            if autopilot:
                self._latest[kind] = msg
            waiters = [w for w in self._waiters if (autopilot or w.any_component) and w.match(msg)]
            listeners = list(self._listeners.get(kind, ())) if autopilot else []
        for waiter in waiters:
            waiter.messages.put(msg)
        for listener in listeners:
            try:
                listener(msg)
            except Exception:
                logger.exception("MAVLink listener for %s", kind)

    def _is_vehicle_heartbeat(self, msg: Any, source: tuple[int, int]) -> bool:
        if self.target_system is not None:
            return source == (self.target_system, self.target_component)
        return msg.type not in _NOT_A_VEHICLE and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID

    def _on_heartbeat(self, msg: Any, source: tuple[int, int], now: float) -> None:
        beat = Heartbeat(
            system_id=source[0],
            component_id=source[1],
            mav_type=int(msg.type),
            autopilot=Autopilot.from_heartbeat(int(msg.autopilot)),
            base_mode=int(msg.base_mode),
            custom_mode=int(msg.custom_mode),
            system_status=int(msg.system_status),
            received=now,
        )
        regained = False
        with self._lock:
            if self.target_system is None:
                self.target_system, self.target_component = source
                logger.info(
                    "MAVLink %s: vehicle %d/%d (%s, type %d)",
                    self.endpoint,
                    source[0],
                    source[1],
                    beat.autopilot.value,
                    beat.mav_type,
                )
            previous = self._heartbeat
            self._heartbeat = beat
            if not self._link_ok:
                self._link_ok = True
                regained = previous is not None
        self._heard.set()
        if previous is not None and previous.mode != beat.mode:
            logger.info("MAVLink %s: mode %s -> %s", self.endpoint, previous.mode, beat.mode)
        if regained:
            logger.warning("MAVLink %s: link regained", self.endpoint)
            if self.on_link_regained is not None:
                self.on_link_regained()

    def _on_statustext(self, msg: Any, now: float) -> None:
        text = str(msg.text)
        chunk_id = int(getattr(msg, "id", 0))
        if chunk_id:
            # MAVLink 2 splits texts over 50 characters into chunks sharing an id; the last
            # chunk is the one that does not fill the field.
            parts = self._chunks.setdefault(chunk_id, [])
            parts.append(text)
            if len(text) >= _STATUSTEXT_CHUNK:
                return
            text = "".join(self._chunks.pop(chunk_id))
        severity = int(msg.severity)
        with self._lock:
            self._texts.append(StatusText(severity, text, now))
        level = logging.WARNING if severity <= mavlink.MAV_SEVERITY_WARNING else logging.INFO
        logger.log(level, "MAVLink %s: vehicle says %r", self.endpoint, text)

    def _timer_loop(self) -> None:
        next_beat = self.monotonic()
        while not self._stop.is_set():
            now = self.monotonic()
            if now >= next_beat:
                next_beat = now + self.heartbeat_period_s
                try:
                    self.send(
                        lambda mav: mav.heartbeat_send(
                            self.mav_type,
                            mavlink.MAV_AUTOPILOT_INVALID,
                            0,
                            0,
                            mavlink.MAV_STATE_ACTIVE,
                        )
                    )
                except Exception:
                    if self._stop.is_set():
                        return
                    logger.exception("MAVLink heartbeat on %s", self.endpoint)
            self._check_link(now)
            self._stop.wait(min(0.1, max(0.0, next_beat - self.monotonic())))

    def _check_link(self, now: float) -> None:
        beat = self._heartbeat
        if beat is None or not self._link_ok or now - beat.received <= self.link_timeout_s:
            return
        with self._lock:
            self._link_ok = False
        logger.warning(
            "MAVLink %s: link lost (no heartbeat for %.1f s)", self.endpoint, now - beat.received
        )
        if self.on_link_lost is not None:
            try:
                self.on_link_lost()
            except Exception:
                logger.exception("on_link_lost callback")
