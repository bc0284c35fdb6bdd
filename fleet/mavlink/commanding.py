"""Commands over a MAVLink link: COMMAND_LONG and COMMAND_INT until acknowledged, message
rates and requests, mode changes, arming and disarming (a part of ``MavlinkLink``)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from fleet.mavlink.errors import (
    CommandDenied,
    CommandTimeout,
    MavlinkError,
    ModeChangeFailed,
    PreArmFailed,
)
from fleet.mavlink.exchange import CommandAck, Heartbeat, LinkCore, StatusText
from fleet.mavlink.modes import custom_mode_of, same_mode, set_mode_params
from fleet.mavlink.wire import mavlink

logger = logging.getLogger("cpcc.mavlink")

# STATUSTEXT lines that explain a refused arming: ArduPilot's "PreArm: ..." and "Arm: ...",
# PX4's "Preflight Fail: ..." and "Arming denied ...".
_ARMING_PREFIXES = ("prearm", "arm", "preflight", "arming")


class Commanding(LinkCore):
    """The commands of a link (see ``fleet.mavlink.link``)."""

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
            wanted = custom_mode_of(beat.autopilot, name, beat.mav_type)
            params = set_mode_params(beat.autopilot, name, beat.mav_type)
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


def _explains_arming(text: StatusText) -> bool:
    return text.text.lower().startswith(_ARMING_PREFIXES)
