"""GUIDED as ArduCopter flies it: the targets a ground station gives and the answers it gets.

- MISSION_ITEM / MISSION_ITEM_INT with current=2 (ArduPilot's "guided mode waypoint", what
  MAVProxy's ``guided`` sent before it used DO_REPOSITION): answered with a MISSION_ACK,
  ACCEPTED, UNSUPPORTED_FRAME for a frame that is not global, UNSUPPORTED for a command other
  than NAV_WAYPOINT, ERROR outside GUIDED, on the ground or outside the fence.
- MAV_CMD_DO_REPOSITION (COMMAND_INT, or COMMAND_LONG with lat/lng in param5/6 and the
  altitude relative to home): switches to GUIDED when param2 has
  MAV_DO_REPOSITION_FLAGS_CHANGE_MODE (DENIED outside GUIDED without it, or for a frame that
  is not global), FAILED for a target that is refused.
- SET_POSITION_TARGET_GLOBAL_INT and SET_POSITION_TARGET_LOCAL_NED (MAV_FRAME_LOCAL_NED:
  metres north, east, down from home, ArduCopter's EKF origin; MAV_FRAME_LOCAL_OFFSET_NED:
  from where the vehicle is): no answer in the protocol, ignored outside GUIDED and before
  take-off as ArduCopter does; a frame it does not fly or a refused target is said once in a
  STATUSTEXT ("Guided: frame 8 not supported"). When they came is kept for PX4, whose
  offboard mode wants them streaming (``SetpointStream``).

A rover, a boat or a sub (``takes_off`` False) follows targets once armed, with no take-off;
a rover and a boat ignore a target's altitude, a sub goes no higher than the surface (its
negative altitudes are depths).

A target outside an enabled fence is refused, as ArduCopter's ModeGuided::set_destination
refuses it: the vehicle stays where it is and no breach follows. Velocity and acceleration
targets are not simulated.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from fleet.geo import Position
from fleet.mavlink.mission import MissionItem
from fleet.mavlink.sim.fence import Fence, fence_names
from fleet.mavlink.sim.targets import GLOBAL_FRAMES, TargetRefused, global_target, local_target
from fleet.mavlink.wire import mavlink

POSITION_IGNORE = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
)
_SETPOINT_LOSS_S = 1.0  # PX4's COM_OF_LOSS_T default


class Vehicle(Protocol):
    """What GUIDED asks of the vehicle (see ``MavSim``)."""

    @property
    def armed(self) -> bool: ...

    @property
    def on_ground(self) -> bool: ...

    @property
    def mode(self) -> str: ...

    def here(self) -> Position: ...

    def go_to(self, target: Position) -> None:
        """Fly straight to ``target`` and hover there (the same target again: nothing new)."""
        ...

    def change_mode(self, mode: str) -> int:
        """Switch modes; the MAV_RESULT."""
        ...


class SetpointStream:
    """When the position targets came, on the wall clock ``wall``: PX4 enters offboard only
    while they stream and leaves it when they stop (COM_OF_LOSS_T)."""

    def __init__(self, wall: Callable[[], float]) -> None:
        self._wall = wall
        self._times: deque[float] = deque(maxlen=8)
        self._last = -math.inf

    def heard(self) -> None:
        """A position target came now."""
        self._last = self._wall()
        self._times.append(self._last)

    def live(self) -> bool:
        """At least two targets within the loss time."""
        wall = self._wall()
        return sum(1 for t in self._times if wall - t <= _SETPOINT_LOSS_S) >= 2

    def lost(self) -> bool:
        """No target within the loss time."""
        return self._wall() - self._last > _SETPOINT_LOSS_S


class Guided:
    """GUIDED's targets for ``vehicle``. ``mode`` is the mode that follows them (GUIDED),
    ``takes_off`` whether the vehicle must be flying first (a copter) or only armed, ``home`` and ``ground_amsl_m`` what relative and absolute altitudes mean, ``send`` sends a
    message from the autopilot, ``text`` a STATUSTEXT (severity, text), ``wall`` is the wall
    clock ``setpoints`` runs on."""

    def __init__(
        self,
        vehicle: Vehicle,
        fence: Fence,
        *,
        mode: str,
        takes_off: bool = True,
        home: Position,
        ground_amsl_m: float,
        send: Callable[[Callable[[Any], None]], None],
        text: Callable[[int, str], None],
        wall: Callable[[], float],
    ) -> None:
        self._vehicle = vehicle
        self._fence = fence
        self.mode = mode
        self._takes_off = takes_off
        self._home = home
        self._ground_amsl_m = ground_amsl_m
        self._send = send
        self._text = text
        self._refused: set[tuple[str, str]] = set()  # (message, reason) already said
        self.setpoints = SetpointStream(wall)

    def target(self, frame: int, lat: float, lng: float, alt: float) -> Position:
        """Where a global-frame target points. Raises TargetRefused."""
        return global_target(
            frame, lat, lng, alt, home=self._home, ground_amsl_m=self._ground_amsl_m
        )

    def refusal(self, target: Position) -> str | None:
        """Why a target is not flown, or None: the vehicle must be flying (a rover, boat or sub:
        armed), the target inside the fence."""
        if not self._vehicle.armed or (self._takes_off and self._vehicle.on_ground):
            return "not flying: arm and take off first" if self._takes_off else "not armed"
        breached = self._fence.breaches(target)
        if breached:
            return f"destination outside {fence_names(breached)}"
        return None

    def on_item(self, msg: Any, reply_to: tuple[int, int]) -> None:
        """A MISSION_ITEM(_INT) with current=2, answered with a MISSION_ACK to ``reply_to``."""
        item = MissionItem.from_message(msg)
        result = int(mavlink.MAV_MISSION_ACCEPTED)
        reason = None
        if item.command != mavlink.MAV_CMD_NAV_WAYPOINT:
            result, reason = int(mavlink.MAV_MISSION_UNSUPPORTED), "only NAV_WAYPOINT"
        elif item.frame not in GLOBAL_FRAMES:
            result = int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
            reason = f"frame {item.frame} not supported"
        elif self._vehicle.mode != self.mode:
            result, reason = int(mavlink.MAV_MISSION_ERROR), f"not in {self.mode}"
        else:
            try:
                target = self.target(item.frame, item.lat, item.lng, item.z)
                reason = self.refusal(target)
            except TargetRefused as exc:
                reason = str(exc)
            if reason is None:
                self._vehicle.go_to(target)
            else:
                result = int(mavlink.MAV_MISSION_ERROR)
        if reason is not None:
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Guided: {reason}")
        system, component = reply_to
        self._send(
            lambda mav: mav.mission_ack_send(
                system, component, result, mavlink.MAV_MISSION_TYPE_MISSION
            )
        )

    def reposition(self, p: tuple[float, ...], frame: int) -> int:
        """MAV_CMD_DO_REPOSITION (ArduCopter's handle_command_int_do_reposition): the seven
        parameters (lat/lng in the fifth and sixth) and the frame; the MAV_RESULT."""
        vehicle = self._vehicle
        change_mode = round(p[1]) & mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
        if vehicle.mode != self.mode and not change_mode:
            return int(mavlink.MAV_RESULT_DENIED)
        try:
            if frame not in GLOBAL_FRAMES:
                raise TargetRefused(f"frame {frame} not supported", unsupported_frame=True)
            if math.isnan(p[6]):  # NaN altitude: stay at this one
                target = Position(p[4], p[5], vehicle.here().alt)
            else:
                target = self.target(frame, p[4], p[5], p[6])
        except (TargetRefused, ValueError) as exc:
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Reposition: {exc}")
            return int(mavlink.MAV_RESULT_DENIED)
        reason = self.refusal(target)
        if reason is not None:
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Reposition: {reason}")
            return int(mavlink.MAV_RESULT_FAILED)
        # The mode changes only once the target is known to be good, as in ArduCopter.
        if (
            vehicle.mode != self.mode
            and vehicle.change_mode(self.mode) != mavlink.MAV_RESULT_ACCEPTED
        ):
            return int(mavlink.MAV_RESULT_FAILED)
        vehicle.go_to(target)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def on_position_target(self, msg: Any) -> None:
        """SET_POSITION_TARGET_GLOBAL_INT or SET_POSITION_TARGET_LOCAL_NED."""
        self.setpoints.heard()
        vehicle = self._vehicle
        if msg.type_mask & POSITION_IGNORE:
            return  # velocity or acceleration targets: not simulated
        if vehicle.mode != self.mode or not vehicle.armed:
            return  # ArduPilot ignores targets outside GUIDED and disarmed
        if self._takes_off and vehicle.on_ground:
            return  # ArduCopter ignores them before take-off
        kind = msg.get_type()
        frame = int(msg.coordinate_frame)
        try:
            if kind == "SET_POSITION_TARGET_LOCAL_NED":
                here = vehicle.here()
                target = local_target(frame, msg.x, msg.y, msg.z, home=self._home, here=here)
            else:
                target = self.target(frame, msg.lat_int / 1e7, msg.lon_int / 1e7, msg.alt)
        except TargetRefused as exc:
            self._refuse_once(kind, str(exc))
            return
        reason = self.refusal(target)
        if reason is not None:
            self._refuse_once(kind, reason)
            return
        vehicle.go_to(target)

    def _refuse_once(self, what: str, reason: str) -> None:
        # Once per reason: a GCS streaming a refused target hears it once, not at its rate.
        if (what, reason) in self._refused:
            return
        self._refused.add((what, reason))
        self._text(mavlink.MAV_SEVERITY_WARNING, f"Guided: {reason}")
