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

Listener callbacks and the link-loss callbacks run on the link's threads: keep them short, and
never call a blocking request (a command) from them.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from fleet.mavlink import params as param_codec
from fleet.mavlink.endpoint import parse_endpoint
from fleet.mavlink.errors import (
    CommandDenied,
    CommandTimeout,
    LinkError,
    LinkLost,
    MavlinkError,
    MissionRejected,
    MissionTimeout,
    ModeChangeFailed,
    ParamRejected,
    ParamTimeout,
    PreArmFailed,
)
from fleet.mavlink.mission import MissionItem
from fleet.mavlink.modes import Autopilot, custom_mode_of, mode_name, same_mode, set_mode_params
from fleet.mavlink.wire import BAD_DATA, connect, drop_closed_tcp_client, encode_text, mavlink

logger = logging.getLogger("cpcc.mavlink")

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
# STATUSTEXT lines that explain a refused arming: ArduPilot's "PreArm: ..." and "Arm: ...",
# PX4's "Preflight Fail: ..." and "Arming denied ...".
_ARMING_PREFIXES = ("prearm", "arm", "preflight", "arming")
_STATUSTEXT_CHUNK = 50  # STATUSTEXT.text is char[50]; a longer text is sent in chunks


@dataclass(frozen=True)
class Heartbeat:
    """The vehicle's last HEARTBEAT, decoded. ``received`` is on the link's monotonic clock."""

    system_id: int
    component_id: int
    mav_type: int
    autopilot: Autopilot
    base_mode: int
    custom_mode: int
    system_status: int
    received: float

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str:
        """The flight mode's name, e.g. "GUIDED" (ArduCopter) or "AUTO.LOITER" (PX4)."""
        return mode_name(self.autopilot, self.custom_mode)


@dataclass(frozen=True)
class StatusText:
    """One STATUSTEXT line from the vehicle (chunks already joined)."""

    severity: int
    text: str
    received: float


@dataclass(frozen=True)
class CommandAck:
    """The COMMAND_ACK that ended a command (its result is ACCEPTED when returned)."""

    command: int
    result: int
    progress: int
    result_param2: int


class _Waiter:
    """Collects the messages a pending request is waiting for (filled by the reader thread)."""

    def __init__(self, match: Callable[[Any], bool], *, any_component: bool = False) -> None:
        self.match = match
        self.any_component = any_component  # also the vehicle's other components' messages
        self.messages: queue.SimpleQueue[Any] = queue.SimpleQueue()

    def get(self, timeout_s: float) -> Any | None:
        try:
            return self.messages.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None


class MavlinkLink:
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
        self._waiters: list[_Waiter] = []
        self._listeners: dict[str, list[Callable[[Any], None]]] = {}
        self._param_types: dict[str, int] = {}

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

    # --- commands -------------------------------------------------------------------------

    def command_long(
        self,
        command: int,
        params: Sequence[float] = (),
        *,
        timeout_s: float | None = None,
        attempts: int | None = None,
        component: int | None = None,
    ) -> CommandAck:
        """Send COMMAND_LONG (up to 7 params, the rest 0) until it is acknowledged.
        ``component``: another component of the vehicle to command (its camera, say), which
        acknowledges it itself; by default the autopilot.

        Each attempt waits ``timeout_s`` (default: the link's) for a COMMAND_ACK of this
        command; re-sent attempts count up the ``confirmation`` field, as the protocol asks, so
        the vehicle can tell a retransmission from a new command. An IN_PROGRESS answer keeps
        waiting without re-sending. Returns the ACCEPTED ack. Raises CommandDenied for any
        other result, CommandTimeout after the last attempt, LinkLost when the link is down.
        """
        values = [float(p) for p in params][:7]
        values += [0.0] * (7 - len(values))
        to = self.target_component if component is None else component

        def send_attempt(confirmation: int) -> None:
            self.send(
                lambda mav: mav.command_long_send(
                    self._target(), to, command, confirmation, *values
                )
            )

        return self._command(command, send_attempt, timeout_s, attempts, component=to)

    def command_int(
        self,
        command: int,
        params: Sequence[float] = (),
        *,
        frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        x: int = 0,
        y: int = 0,
        z: float = 0.0,
        timeout_s: float | None = None,
        attempts: int | None = None,
    ) -> CommandAck:
        """Send COMMAND_INT (param1..4, x/y as degrees * 1e7, z) until it is acknowledged.

        Like ``command_long``, except that COMMAND_INT has no ``confirmation`` field: a
        retransmission is the same message again. Raises as ``command_long`` does.
        """
        values = [float(p) for p in params][:4]
        values += [0.0] * (4 - len(values))

        def send_attempt(_confirmation: int) -> None:
            self.send(
                lambda mav: mav.command_int_send(
                    self._target(), self.target_component, frame, command, 0, 0, *values, x, y, z
                )
            )

        return self._command(command, send_attempt, timeout_s, attempts)

    def _command(
        self,
        command: int,
        send_attempt: Callable[[int], None],
        timeout_s: float | None,
        attempts: int | None,
        *,
        component: int | None = None,
    ) -> CommandAck:
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        answering = self.target_component if component is None else component
        tries = self.command_attempts if attempts is None else attempts

        def is_ack(msg: Any) -> bool:
            # MAVLink 2 acks name who asked (0 from senders that leave it out).
            return (
                msg.get_type() == "COMMAND_ACK"
                and msg.command == command
                and msg.get_srcComponent() == answering
                and getattr(msg, "target_system", 0) in (0, self.source_system)
            )

        # COMMAND_ACK names only the command id, so two commands of the same id in flight
        # could not be told apart: one command at a time keeps the matching exact.
        other = answering != self.target_component
        with self._command_lock, self.waiting(is_ack, any_component=other) as waiter:
            for attempt in range(tries):
                self._require_link()
                send_attempt(attempt)
                deadline = self.monotonic() + timeout
                while True:
                    ack = waiter.get(deadline - self.monotonic())
                    if ack is None:
                        break
                    if ack.result == mavlink.MAV_RESULT_IN_PROGRESS:
                        deadline = self.monotonic() + timeout  # still working: keep waiting
                        continue
                    result = CommandAck(
                        command, int(ack.result), int(ack.progress), int(ack.result_param2)
                    )
                    if result.result != mavlink.MAV_RESULT_ACCEPTED:
                        raise CommandDenied(command, result.result)
                    return result
                logger.info("%s: no COMMAND_ACK (attempt %d of %d)", command, attempt + 1, tries)
        raise CommandTimeout(command, tries)

    def set_message_interval(self, message_id: int, rate_hz: float) -> None:
        """Ask the vehicle to send a message at ``rate_hz`` (0 or less: stop sending it).

        MAV_CMD_SET_MESSAGE_INTERVAL: param1 is the message id, param2 the interval in
        microseconds (-1 disables the stream, 0 would mean "your default"). Raises as
        ``command_long`` does.
        """
        interval_us = 1e6 / rate_hz if rate_hz > 0 else -1.0
        self.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (message_id, interval_us))

    def request_message(self, message_id: int, *, timeout_s: float | None = None) -> Any:
        """Ask for one message now (MAV_CMD_REQUEST_MESSAGE) and return it when it comes.

        Raises as ``command_long`` does, and CommandTimeout if the message does not follow
        the acknowledgement within the timeout.
        """
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        with self.waiting(lambda msg: msg.get_msgId() == message_id) as waiter:
            self.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, (message_id,), timeout_s=timeout)
            msg = waiter.get(timeout)
        if msg is None:
            raise CommandTimeout(mavlink.MAV_CMD_REQUEST_MESSAGE, 1)
        return msg

    def set_mode(self, name: str, *, timeout_s: float | None = None) -> None:
        """Switch the flight mode by name ("GUIDED", "RTL", "OFFBOARD", "AUTO.LOITER", ...).

        MAV_CMD_DO_SET_MODE, then waits until a heartbeat shows the mode (an autopilot may
        accept the command and still stay where it is). Does nothing when already in the mode.
        Raises MavlinkError (permanent) for a name unknown for this autopilot, CommandDenied
        when refused, ModeChangeFailed when no heartbeat shows the mode in time.
        """
        beat = self._require_link()
        try:
            wanted = custom_mode_of(beat.autopilot, name)
            params = set_mode_params(beat.autopilot, name)
        except KeyError:
            raise MavlinkError(
                f"unknown flight mode {name!r} for {beat.autopilot.value}", permanent=True
            ) from None
        if same_mode(beat.autopilot, beat.custom_mode, wanted):
            return
        self.command_long(mavlink.MAV_CMD_DO_SET_MODE, params)
        self._await_heartbeat(
            lambda hb: same_mode(hb.autopilot, hb.custom_mode, wanted),
            timeout_s,
            f"the vehicle acknowledged mode {name} but its heartbeat does not show it",
        )

    def arm(self, *, timeout_s: float | None = None) -> None:
        """Arm the motors (MAV_CMD_COMPONENT_ARM_DISARM, param1 = 1); nothing if armed.

        Raises PreArmFailed with the vehicle's STATUSTEXT reasons when arming is refused,
        ModeChangeFailed when it is acknowledged but the heartbeat never shows "armed", and as
        ``command_long`` does otherwise.
        """
        beat = self._require_link()
        if beat.armed:
            return
        sent = self.monotonic()
        try:
            self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,))
        except CommandDenied as exc:
            raise PreArmFailed(exc.result, self._arming_reasons(sent)) from None
        self._await_heartbeat(
            lambda hb: hb.armed, timeout_s, "arming was acknowledged but the vehicle is not armed"
        )

    def disarm(self, *, force: bool = False, timeout_s: float | None = None) -> None:
        """Disarm the motors; nothing if disarmed.

        ``force`` sends the magic 21196 in param2, which makes ArduPilot and PX4 disarm even in
        flight (the vehicle falls): only for emergencies. Raises as ``command_long`` does, and
        ModeChangeFailed when the heartbeat still shows "armed".
        """
        beat = self._require_link()
        if not beat.armed:
            return
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (0.0, 21196.0 if force else 0.0))
        self._await_heartbeat(
            lambda hb: not hb.armed,
            timeout_s,
            "disarming was acknowledged but the vehicle is armed",
        )

    def _arming_reasons(self, since: float) -> list[str]:
        """The STATUSTEXT lines explaining a refused arming.

        ArduPilot sends its "PreArm: ..." lines before the COMMAND_ACK, but rate-limits
        STATUSTEXT, so a reason can also arrive just after it: wait briefly for one. Without a
        fresh line, the last "PreArm" lines it repeated on its own (every 30 s) are the answer.
        """
        deadline = self.monotonic() + min(1.0, self.command_timeout_s)
        with self.waiting(lambda msg: msg.get_type() == "STATUSTEXT") as waiter:
            while True:
                lines = [t.text for t in self.status_texts(since) if _explains_arming(t)]
                if lines or self.monotonic() >= deadline:
                    break
                waiter.get(deadline - self.monotonic())
        if not lines:
            recent = self.status_texts(since - 30.0)
            lines = [t.text for t in recent if t.text.lower().startswith("prearm")]
        return list(dict.fromkeys(lines))

    def _await_heartbeat(
        self, condition: Callable[[Heartbeat], bool], timeout_s: float | None, failure: str
    ) -> Heartbeat:
        timeout = max(2.5 * self.heartbeat_period_s, 2 * self.command_timeout_s)
        deadline = self.monotonic() + (timeout if timeout_s is None else timeout_s)
        with self.waiting(lambda msg: msg.get_type() == "HEARTBEAT") as waiter:
            while True:
                beat = self._heartbeat
                if beat is not None and condition(beat):
                    return beat
                remaining = deadline - self.monotonic()
                if remaining <= 0:
                    raise ModeChangeFailed(failure)
                waiter.get(min(remaining, 0.5))

    # --- parameters -----------------------------------------------------------------------

    def param_get(self, name: str, *, timeout_s: float | None = None) -> float:
        """Read one parameter (PARAM_REQUEST_READ by name); returns its value.

        Integer parameters come back as whole floats (byte-wise encoding undone for PX4).
        Raises ParamTimeout when no PARAM_VALUE comes after every attempt (an unknown name
        gets no answer either), LinkLost when the link is down.
        """
        msg = self._param_exchange(
            name,
            lambda mav: mav.param_request_read_send(
                self._target(), self.target_component, encode_text(name, 16), -1
            ),
            timeout_s,
        )
        return self._decode_param(msg)

    def param_set(
        self,
        name: str,
        value: float,
        *,
        param_type: int | None = None,
        timeout_s: float | None = None,
    ) -> float:
        """Write one parameter and wait for the vehicle's PARAM_VALUE with the new value.

        ``param_type`` (MAV_PARAM_TYPE) is taken from an earlier PARAM_VALUE when not given
        (the parameter is read first if none was seen). Returns the value the vehicle holds.
        Raises ParamRejected (permanent) when the echo shows another value, ParamTimeout when
        no echo comes, ValueError when the value does not fit an integer type.
        """
        if param_type is None:
            param_type = self._param_types.get(name)
            if param_type is None:
                self.param_get(name, timeout_s=timeout_s)
                param_type = self._param_types.get(name, param_codec.REAL32)
        bytewise = self.autopilot is Autopilot.PX4
        wire = param_codec.encode(value, param_type, bytewise=bytewise)
        wanted = param_codec.decode(param_codec.as_float32(wire), param_type, bytewise=bytewise)
        msg = self._param_exchange(
            name,
            lambda mav: mav.param_set_send(
                self._target(), self.target_component, encode_text(name, 16), wire, param_type
            ),
            timeout_s,
        )
        held = self._decode_param(msg)
        if param_codec.as_float32(held) != param_codec.as_float32(wanted):
            raise ParamRejected(f"parameter {name}: wrote {value!r}, the vehicle holds {held!r}")
        return held

    def _param_exchange(
        self, name: str, send: Callable[[Any], None], timeout_s: float | None
    ) -> Any:
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        with self.waiting(
            lambda msg: msg.get_type() == "PARAM_VALUE" and msg.param_id == name
        ) as waiter:
            for _attempt in range(self.command_attempts):
                self._require_link()
                self.send(send)
                msg = waiter.get(timeout)
                if msg is not None:
                    return msg
        raise ParamTimeout(name, self.command_attempts)

    def _decode_param(self, msg: Any) -> float:
        return param_codec.decode(
            float(msg.param_value),
            int(msg.param_type),
            bytewise=self.autopilot is Autopilot.PX4,
        )

    # --- missions (and fences) ------------------------------------------------------------

    def upload_mission(
        self,
        items: Sequence[MissionItem],
        mission_type: int,
        *,
        timeout_s: float | None = None,
    ) -> None:
        """Upload a list with the mission protocol (the fence with MAV_MISSION_TYPE_FENCE).

        MISSION_COUNT, then the vehicle asks for each item (MISSION_REQUEST_INT, or the older
        MISSION_REQUEST) and gets a MISSION_ITEM_INT, and ends with MISSION_ACK. When the
        vehicle goes quiet the last message is sent again (``command_attempts`` times in a row
        at most). An empty list clears the vehicle's list. Raises MissionRejected with the
        vehicle's MAV_MISSION_RESULT, MissionTimeout when it stalls, LinkLost.
        """
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        numbered = [item.with_seq(seq) for seq, item in enumerate(items)]

        def send_count() -> None:
            self.send(
                lambda mav: mav.mission_count_send(
                    self._target(), self.target_component, len(numbered), mission_type
                )
            )

        def send_item(item: MissionItem) -> None:
            self.send(
                lambda mav: item.send(mav, self._target(), self.target_component, mission_type)
            )

        def is_answer(msg: Any) -> bool:
            kind = msg.get_type()
            if kind not in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"):
                return False
            return getattr(msg, "mission_type", 0) == mission_type

        with self._mission_lock, self.waiting(is_answer) as waiter:
            resend: Callable[[], None] = send_count
            requested: set[int] = set()
            silent = 0
            self._require_link()
            send_count()
            while True:
                msg = waiter.get(timeout)
                if msg is None:
                    silent += 1
                    if silent >= self.command_attempts:
                        raise MissionTimeout(
                            f"mission upload (type {mission_type}) stalled after "
                            f"{len(requested)} of {len(numbered)} items"
                        )
                    self._require_link()
                    resend()
                    continue
                silent = 0
                if msg.get_type() == "MISSION_ACK":
                    if msg.type != mavlink.MAV_MISSION_ACCEPTED:
                        raise MissionRejected(int(msg.type), mission_type)
                    if len(requested) == len(numbered):
                        return
                    # An ACCEPTED ack before every item was asked for answers an earlier,
                    # abandoned transfer: keep going with this one.
                    continue
                seq = int(msg.seq)
                if not 0 <= seq < len(numbered):
                    continue
                requested.add(seq)
                item = numbered[seq]
                # MISSION_ITEM_INT answers MISSION_REQUEST too: ArduPilot and PX4 accept it,
                # and it keeps the coordinates exact (MISSION_ITEM's are float32 degrees).
                send_item(item)
                resend = functools.partial(send_item, item)

    def download_mission(
        self, mission_type: int, *, timeout_s: float | None = None
    ) -> list[MissionItem]:
        """Read a list back from the vehicle (MISSION_REQUEST_LIST, then each item).

        Returns the items in order. Raises MissionTimeout when the vehicle stops answering,
        LinkLost.
        """
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        target = self._target

        def is_count(msg: Any) -> bool:
            return bool(msg.get_type() == "MISSION_COUNT" and msg.mission_type == mission_type)

        def is_item(seq: int) -> Callable[[Any], bool]:
            return lambda msg: bool(
                msg.get_type() == "MISSION_ITEM_INT"
                and msg.seq == seq
                and msg.mission_type == mission_type
            )

        def request_item(seq: int) -> Callable[[Any], None]:
            return lambda mav: mav.mission_request_int_send(
                target(), self.target_component, seq, mission_type
            )

        with self._mission_lock:
            with self.waiting(is_count) as waiter:
                count_msg = self._ask(
                    waiter,
                    lambda mav: mav.mission_request_list_send(
                        target(), self.target_component, mission_type
                    ),
                    timeout,
                )
            items: list[MissionItem] = []
            for seq in range(int(count_msg.count)):
                with self.waiting(is_item(seq)) as waiter:
                    msg = self._ask(waiter, request_item(seq), timeout)
                items.append(MissionItem.from_message(msg).with_seq(seq))
            self.send(
                lambda mav: mav.mission_ack_send(
                    target(), self.target_component, mavlink.MAV_MISSION_ACCEPTED, mission_type
                )
            )
            return items

    def _ask(self, waiter: _Waiter, send: Callable[[Any], None], timeout: float) -> Any:
        for _attempt in range(self.command_attempts):
            self._require_link()
            self.send(send)
            msg = waiter.get(timeout)
            if msg is not None:
                return msg
        raise MissionTimeout(f"mission download: no answer after {self.command_attempts} attempts")

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
    ) -> Iterator[_Waiter]:
        """Collect the vehicle's messages that ``match`` accepts for the block's duration
        (``get(timeout_s)`` takes the next): registered before the block sends what they
        answer, so no answer is lost. ``any_component``: from any of its components."""
        waiter = _Waiter(match, any_component=any_component)
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

    def _dispatch(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == BAD_DATA:
            return
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


def _explains_arming(text: StatusText) -> bool:
    return text.text.lower().startswith(_ARMING_PREFIXES)
