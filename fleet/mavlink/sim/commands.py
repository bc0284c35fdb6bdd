"""The command protocol (COMMAND_LONG and COMMAND_INT) for one component of the vehicle.

Every command is answered with a COMMAND_ACK from that component (MAV_RESULT_UNSUPPORTED for
one it does not know). A retransmission (COMMAND_LONG's confirmation > 0) of the command just
executed is answered again without executing it twice: its ACK was lost. Both messages end up
as the same seven numbers (COMMAND_INT's x/y in degrees) and a frame: COMMAND_LONG has none,
and ArduPilot reads its positions as relative to home.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from typing import Any

from fleet.mavlink.sim import camera as camera_protocol
from fleet.mavlink.wire import mavlink

# A MAV_RESULT, and what to send after the COMMAND_ACK (a requested message), if anything.
Outcome = tuple[int, Callable[[], None] | None]
Executor = Callable[[int, tuple[float, ...], int], Outcome]


def command_values(msg: Any) -> tuple[float, ...]:
    """The seven parameters of a COMMAND_LONG or COMMAND_INT (positions in degrees)."""
    if msg.get_type() == "COMMAND_INT":
        values = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x / 1e7, msg.y / 1e7, msg.z)
    else:
        values = (
            msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7
        )  # fmt: skip
    return tuple(float(v) for v in values)


def command_frame(msg: Any) -> int:
    if msg.get_type() == "COMMAND_INT":
        return int(msg.frame)
    return int(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT)


def addressee(msg: Any) -> int:
    """The component a command is for: its target_component, except that a camera command sent
    to every component (0) is the camera's."""
    target = int(msg.target_component)
    if target != 0:
        return target
    command = int(msg.command)
    if command in camera_protocol.COMMANDS or (
        command == mavlink.MAV_CMD_REQUEST_MESSAGE and round(msg.param1) in camera_protocol.MESSAGES
    ):
        return camera_protocol.COMPONENT_ID
    return 0


class CommandServer:
    """Runs commands with ``execute`` (command, seven parameters, frame) and acknowledges them
    with ``send`` (it gets pymavlink's MAVLink object of the component). ``seen`` holds the
    confirmation of every command received (0 for COMMAND_INT); a command id in ``ignored`` is
    neither executed nor acknowledged."""

    def __init__(self, execute: Executor, send: Callable[[Callable[[Any], None]], None]) -> None:
        self._execute = execute
        self._send = send
        self.seen: dict[int, list[int]] = defaultdict(list)
        self.ignored: set[int] = set()
        self._last: tuple[tuple[int, tuple[float, ...]], int] | None = None

    def handle(self, msg: Any, reply_to: tuple[int, int]) -> None:
        command = int(msg.command)
        confirmation = 0 if msg.get_type() == "COMMAND_INT" else int(msg.confirmation)
        self.seen[command].append(confirmation)
        if command in self.ignored:
            return
        key = (command, command_values(msg))
        after: Callable[[], None] | None = None
        if confirmation > 0 and self._last is not None and self._last[0] == key:
            # A retransmission of the command just executed (its ACK was lost): answer again
            # without doing it twice, which is what the confirmation counter is for.
            result = self._last[1]
        else:
            result, after = self._execute(command, key[1], command_frame(msg))
        self._last = (key, result)
        system, component = reply_to
        self._send(lambda mav: mav.command_ack_send(command, result, 0, 0, system, component))
        if after is not None:
            after()
