"""Typed errors of the MAVLink link and driver.

Every error says whether it is ``permanent``: True when doing the same thing again cannot work
until something changes (the vehicle's configuration, its state, an operator); False when a
retry later may succeed (a lost packet, a link that comes back, a vehicle that is busy). The
RV worker uses this to decide between "try again" and "take the vehicle out of service".
"""

from __future__ import annotations

from collections.abc import Sequence

from fleet.driving import DriverError, LinkDown
from fleet.mavlink.wire import mavlink

# MAV_RESULT names for messages (the dialect's enum table has them, but a plain dict keeps
# this module readable and independent of how pymavlink spells its enum entries).
RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
    7: "COMMAND_LONG_ONLY",
    8: "COMMAND_INT_ONLY",
    9: "COMMAND_UNSUPPORTED_MAV_FRAME",
}

# Results after which sending the same command again is pointless: DENIED (invalid in this
# state or with these parameters), UNSUPPORTED, FAILED (the spec: "a problem that must be
# fixed before the command can succeed"), and the wrong-encoding answers. TEMPORARILY_REJECTED
# (busy) and CANCELLED may succeed later.
_PERMANENT_RESULTS = frozenset({2, 3, 4, 7, 8, 9})


def command_name(command: int) -> str:
    """``MAV_CMD_NAV_TAKEOFF`` for 22: the dialect's name of a command id, or the number."""
    entry = mavlink.enums.get("MAV_CMD", {}).get(command)
    return str(entry.name) if entry is not None else str(command)


def result_name(result: int) -> str:
    """``DENIED`` for 2: the name of a MAV_RESULT."""
    return RESULT_NAMES.get(result, str(result))


class MavlinkError(DriverError):
    """Base of every error of ``fleet.mavlink``; ``permanent`` says whether a retry can help.
    A kind of the control loop's ``DriverError``, which is all the loop catches."""


class LinkError(MavlinkError):
    """The connection cannot be opened: a malformed connection string, a missing device."""

    permanent = True


class LinkLost(MavlinkError, LinkDown):
    """No heartbeat from the vehicle within the link timeout (or none at all on connecting).

    Not permanent: a radio link often comes back.
    """

    permanent = False


class UnsupportedVehicle(MavlinkError):
    """The vehicle's heartbeat names an autopilot or airframe this driver cannot fly."""

    permanent = True


class MavlinkTimeout(MavlinkError):
    """A request was sent (and re-sent) but never answered. Not permanent."""

    permanent = False


class CommandTimeout(MavlinkTimeout):
    """A COMMAND_LONG/COMMAND_INT got no COMMAND_ACK after every attempt."""

    def __init__(self, command: int, attempts: int) -> None:
        self.command = command
        self.attempts = attempts
        super().__init__(f"{command_name(command)}: no COMMAND_ACK after {attempts} attempt(s)")


class ParamTimeout(MavlinkTimeout):
    """A parameter read or write got no PARAM_VALUE after every attempt."""

    def __init__(self, name: str, attempts: int) -> None:
        self.name = name
        self.attempts = attempts
        super().__init__(f"parameter {name}: no PARAM_VALUE after {attempts} attempt(s)")


class MissionTimeout(MavlinkTimeout):
    """A mission (fence) transfer stalled: the vehicle stopped requesting or acknowledging."""


class CommandDenied(MavlinkError):
    """The vehicle answered a command with a result other than ACCEPTED.

    ``command`` is the MAV_CMD id, ``result`` the MAV_RESULT. Permanent for DENIED,
    UNSUPPORTED, FAILED and the wrong-encoding results; not for TEMPORARILY_REJECTED or
    CANCELLED.
    """

    def __init__(self, command: int, result: int, detail: str = "") -> None:
        self.command = command
        self.result = result
        message = f"{command_name(command)} answered {result_name(result)}"
        super().__init__(
            f"{message}: {detail}" if detail else message,
            permanent=result in _PERMANENT_RESULTS,
        )


class PreArmFailed(CommandDenied):
    """Arming was refused; ``lines`` are the vehicle's STATUSTEXT reasons ("PreArm: ...").

    Not permanent: most pre-arm failures clear by themselves (GPS lock, EKF settling) or after
    an operator's action (a charged battery), so the vehicle may be tried again later.
    """

    def __init__(self, result: int, lines: Sequence[str]) -> None:
        self.lines = list(lines)
        reasons = "; ".join(self.lines) if self.lines else "the vehicle gave no reason"
        super().__init__(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, result, reasons)
        self.permanent = False


class ModeChangeFailed(MavlinkError):
    """The vehicle acknowledged a mode change but its heartbeat never showed the new mode."""

    permanent = False


class ParamRejected(MavlinkError):
    """A parameter write came back with another value (out of range, read-only, unknown)."""

    permanent = True


class MissionRejected(MavlinkError):
    """The vehicle ended a mission (fence) upload with a MISSION_ACK error.

    ``result`` is the MAV_MISSION_RESULT. Permanent except for MAV_MISSION_ERROR (generic) and
    MAV_MISSION_OPERATION_CANCELLED (another transfer interfered), which may work again.
    """

    def __init__(self, result: int, mission_type: int) -> None:
        self.result = result
        self.mission_type = mission_type
        entry = mavlink.enums.get("MAV_MISSION_RESULT", {}).get(result)
        name = entry.name if entry is not None else str(result)
        retryable = {mavlink.MAV_MISSION_ERROR, mavlink.MAV_MISSION_OPERATION_CANCELLED}
        super().__init__(
            f"upload of mission type {mission_type} refused: {name}",
            permanent=result not in retryable,
        )


class VehicleTookOver(MavlinkError):
    """The vehicle left the driver's control: a pilot or a failsafe switched its mode.

    Permanent for this flight: the driver does not fight a failsafe (battery, fence, radio)
    or a pilot; ``mode`` is the mode the vehicle is in.
    """

    permanent = True

    def __init__(self, mode: str) -> None:
        self.mode = mode
        super().__init__(f"the vehicle switched to {mode} by itself: not commanding it further")
