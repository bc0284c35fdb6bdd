"""The command protocol (COMMAND_LONG and COMMAND_INT) for one component of the vehicle, and
the autopilot's commands, arming and flight modes.

``CommandServer`` answers every command with a COMMAND_ACK from its component
(MAV_RESULT_UNSUPPORTED for one it does not know). A retransmission (COMMAND_LONG's
confirmation > 0) of the command just executed is answered again without executing it twice:
its ACK was lost. Both messages end up as the same seven numbers (COMMAND_INT's x/y in degrees)
and a frame: COMMAND_LONG has none, and ArduPilot reads its positions as relative to home.

``Commander`` is the autopilot's arming and modes, and the commands that change them or move
the vehicle, as ArduCopter (or PX4, ArduRover, ArduSub) runs them. A rover, a boat and a sub
neither take off nor land (UNSUPPORTED, as ArduRover and ArduSub answer): they move once armed,
in GUIDED or AUTO; a rover's HOLD stops it where it is, its RTL drives home and stops there
(armed, as ArduRover stays); a sub's SURFACE rises where it is. Each may disarm anywhere: a
rover stops, a sub floats up to the surface.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from typing import Any

from fleet.mavlink.mission import MissionItem
from fleet.mavlink.modes import Autopilot, mode_name, px4_custom_mode
from fleet.mavlink.sim import camera as camera_protocol
from fleet.mavlink.sim.auto import MissionRunner
from fleet.mavlink.sim.fence import Fence
from fleet.mavlink.sim.flavours import Flavour
from fleet.mavlink.sim.flight import LANDED, TOOK_OFF, Flight, Pilot
from fleet.mavlink.sim.guided import Guided
from fleet.mavlink.sim.params import ParamServer
from fleet.mavlink.sim.transport import Build, reply_to
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


class Commander:
    """The autopilot's arming and flight modes, and the commands that change them or fly
    ``flight``, as the ``flavour`` of autopilot runs them (``execute``). AUTO (``auto``) flies
    the mission ``mission`` returns, GUIDED (``guided``) the targets a ground station sends,
    refused outside ``fence``. ``ground_amsl_m`` is what AMSL altitudes are measured from;
    below ``arm_min_battery`` it refuses to arm. ``send`` sends from the autopilot, ``text``
    a STATUSTEXT (severity, text), ``wall`` is the wall clock, ``log`` tells the operator
    what the flight does (mode changes, take-off, landing)."""

    def __init__(
        self,
        flight: Flight,
        params: ParamServer,
        fence: Fence,
        mission: Callable[[], Sequence[MissionItem]],
        *,
        flavour: Flavour,
        ground_amsl_m: float,
        arm_min_battery: float,
        send: Callable[[Build], None],
        text: Callable[[int, str], None],
        wall: Callable[[], float],
        log: Callable[[str], None] = lambda line: None,
    ) -> None:
        self._flight = flight
        self._log = log
        self._params = params
        self._flavour = flavour
        self._ground_amsl_m = ground_amsl_m
        self._arm_min_battery = arm_min_battery
        self._send = send
        self._text = text
        self._wall = wall
        self.armed = False
        self.armed_wall = 0.0  # when it armed, on the wall clock
        self.mode = flavour.initial_mode
        self.prearm_failure: str | None = None  # a test's reason to refuse arming
        pilot = Pilot(flight, self, ground_amsl_m=ground_amsl_m)
        self.auto = MissionRunner(
            pilot,
            mission,
            send,
            lambda line: text(mavlink.MAV_SEVERITY_INFO, line),
            first_seq=flavour.mission_first_seq,
            takes_off=flavour.takes_off,
            passed_over=flavour.unsupported,
        )
        self.guided = Guided(
            pilot,
            fence,
            mode=flavour.follows_targets,
            takes_off=flavour.takes_off,
            home=flight.home,
            ground_amsl_m=ground_amsl_m,
            send=send,
            text=text,
            wall=wall,
        )

    def execute(self, command: int, p: tuple[float, ...], frame: int) -> Outcome:
        """Run a command (``frame``: where its positions are); returns its MAV_RESULT and what
        to send after the ACK, if anything."""
        f = self._flavour
        accepted = mavlink.MAV_RESULT_ACCEPTED
        if command in f.unsupported:
            return mavlink.MAV_RESULT_UNSUPPORTED, None
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                return self._arm(), None
            return self._disarm(force=round(p[1]) == 21196), None
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            return self._set_mode_command(p), None
        if command == mavlink.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6]), None
        if command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH and f.rtl is not None:
            return self.change_mode(f.rtl), None
        if command == mavlink.MAV_CMD_NAV_LAND:
            return self.change_mode(f.land), None
        if command == mavlink.MAV_CMD_DO_FENCE_ENABLE:
            if "FENCE_ENABLE" not in self._params:
                return mavlink.MAV_RESULT_UNSUPPORTED, None
            self._params.set("FENCE_ENABLE", 1.0 if p[0] >= 0.5 else 0.0)
            return accepted, None
        if command == mavlink.MAV_CMD_DO_REPOSITION:
            return self.guided.reposition(p, frame), None
        if command == mavlink.MAV_CMD_MISSION_START:
            return self._mission_start(round(p[0])), None
        if command == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            running = self.mode == f.mission and self.armed
            if not self.auto.set_current(round(p[0]), running=running):
                return mavlink.MAV_RESULT_DENIED, None
            return accepted, None
        if command == mavlink.MAV_CMD_BATTERY_RESET:
            # ArduPilot's "a fresh battery is in": param2 is its charge in percent.
            self._flight.reset_battery(min(100.0, max(0.0, p[1])) / 100.0)
            return accepted, None
        return mavlink.MAV_RESULT_UNSUPPORTED, None

    def handle(self, msg: Any) -> bool:
        """Handle a message that sets the mode, GUIDED's target or the mission's current item;
        returns whether it did."""
        kind = msg.get_type()
        if kind in ("MISSION_ITEM", "MISSION_ITEM_INT") and msg.current == 2:
            # ArduPilot's "guided mode waypoint", not an item of the mission.
            self.guided.on_item(msg, reply_to(msg))
        elif kind in ("SET_POSITION_TARGET_GLOBAL_INT", "SET_POSITION_TARGET_LOCAL_NED"):
            self.guided.on_position_target(msg)
        elif kind == "SET_MODE":
            self._on_set_mode(msg)
        elif kind == "MISSION_SET_CURRENT":
            self._on_mission_set_current(msg)
        else:
            return False
        return True

    def tick(self) -> None:
        """The flight's manoeuvres end when their time has come, and AUTO flies on."""
        f = self._flavour
        event = self._flight.advance()
        if event in (TOOK_OFF, LANDED):
            p = self._flight.position_at(self._flight.now())
            done = "took off" if event == TOOK_OFF else "landed"
            self._log(f"{done} at {p.lat:.6f}, {p.lng:.6f}, {p.alt:.1f} m")
        if event == TOOK_OFF and f.after_takeoff is not None and self.mode == f.takeoff_mode:
            self.mode = f.after_takeoff
        elif event == LANDED and self.armed and f.takes_off:
            self.stop_motors()  # ArduCopter disarms by itself once landed
        if self.mode == f.mission:
            self.auto.tick()

    # --- arming -----------------------------------------------------------------------------

    def arming_refusal(self) -> str | None:
        """Why arming would be refused now, or None."""
        if self.prearm_failure is not None:
            return self.prearm_failure
        if self.mode not in self._flavour.armable:
            return "Mode not armable"
        if self._flight.battery(self._flight.now()) < self._arm_min_battery:
            return "Battery 1 below minimum arming capacity"
        return None

    def stop_motors(self) -> None:
        """Disarm (on the ground, or dropping where it is)."""
        self.armed = False
        self._text(mavlink.MAV_SEVERITY_INFO, "Disarming motors")

    def _arm(self) -> int:
        if self.armed:
            return int(mavlink.MAV_RESULT_ACCEPTED)
        refusal = self.arming_refusal()
        if refusal is not None:
            # ArduPilot tells why in a STATUSTEXT before it answers the command.
            self._text(mavlink.MAV_SEVERITY_CRITICAL, self._flavour.refusal_prefix + refusal)
            return int(mavlink.MAV_RESULT_DENIED)
        self.armed = True
        self.armed_wall = self._wall()
        self._text(mavlink.MAV_SEVERITY_INFO, "Arming motors")
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _disarm(self, *, force: bool) -> int:
        if not self.armed:
            return int(mavlink.MAV_RESULT_ACCEPTED)
        flight = self._flight
        if not flight.on_ground:
            now = flight.now()
            if not flight.takes_off:
                # A rover or boat stops where it is; a sub, buoyant, floats up to the surface.
                if flight.here().alt < flight.home.alt:
                    flight.start_landing(now)
                else:
                    flight.touchdown(now)
            elif not force:
                self._text(mavlink.MAV_SEVERITY_CRITICAL, "Disarm: vehicle is flying")
                return int(mavlink.MAV_RESULT_FAILED)
            else:
                # Forced disarm in the air: the motors stop and the copter drops where it is.
                flight.touchdown(now)
        self.stop_motors()
        return int(mavlink.MAV_RESULT_ACCEPTED)

    # --- modes ------------------------------------------------------------------------------

    def change_mode(self, mode: str) -> int:
        """Switch to a mode (a name); returns the MAV_RESULT."""
        f = self._flavour
        known = f.armable | f.hold | {f.follows_targets, f.land, f.mission}
        if mode not in known and mode != f.rtl:
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Mode change to {mode} failed")
            return int(mavlink.MAV_RESULT_FAILED)
        if mode == f.follows_targets and f.setpoint_stream and not self.guided.setpoints.live():
            # PX4 enters offboard only while setpoints are already streaming.
            self._text(mavlink.MAV_SEVERITY_WARNING, "Offboard: no setpoint stream")
            return int(mavlink.MAV_RESULT_DENIED)
        if mode == self.mode:
            return int(mavlink.MAV_RESULT_ACCEPTED)
        if mode == f.mission:
            refusal = self.auto.refusal(armed=self.armed)
            if refusal is not None:
                self._text(mavlink.MAV_SEVERITY_WARNING, f"Mode change to {mode} failed: {refusal}")
                return int(mavlink.MAV_RESULT_FAILED)
        flight = self._flight
        now = flight.now()
        self._log(f"mode {self.mode} -> {mode}")
        self.mode = mode
        if mode == f.mission:
            self.auto.start()  # the next tick begins (or resumes) the current item
        # A rover, boat or sub obeys a mode wherever it is parked too (RTL drives home).
        if not flight.on_ground or (not f.takes_off and self.armed):
            if mode == f.rtl:
                flight.start_return(now)
            elif mode == f.land:
                flight.start_landing(now)
            elif mode in f.hold or mode == f.follows_targets:
                flight.hold(now)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def land_now(self, now: float) -> None:
        """LAND without a mode change's checks, landing where it is (a failsafe)."""
        self.mode = self._flavour.land
        self._flight.start_landing(now)

    def _on_set_mode(self, msg: Any) -> None:
        """The deprecated SET_MODE message: ArduPilot answers it with a COMMAND_ACK whose
        command is the message's id."""
        if not msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return
        f = self._flavour
        result = self.change_mode(mode_name(f.autopilot, int(msg.custom_mode), f.mav_type))
        system, component = reply_to(msg)
        self._send(
            lambda mav: mav.command_ack_send(
                mavlink.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, system, component
            )
        )

    def _set_mode_command(self, p: tuple[float, ...]) -> int:
        if not round(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return int(mavlink.MAV_RESULT_UNSUPPORTED)
        autopilot = self._flavour.autopilot
        if autopilot is Autopilot.PX4:
            custom = px4_custom_mode(round(p[1]), round(p[2]))
        else:
            custom = round(p[1])
        return self.change_mode(mode_name(autopilot, custom, self._flavour.mav_type))

    # --- flying -----------------------------------------------------------------------------

    def _takeoff(self, altitude: float) -> int:
        f, flight = self._flavour, self._flight
        if not self.armed or not flight.on_ground:
            return int(mavlink.MAV_RESULT_FAILED)
        if f.takeoff_in is not None and self.mode not in f.takeoff_in:
            return int(mavlink.MAV_RESULT_FAILED)
        home = flight.home
        if f.takeoff_alt_amsl:
            # PX4: param7 is AMSL; NaN means "the default take-off altitude".
            above_ground = (
                home.alt + flight.spec.takeoff_alt_m
                if math.isnan(altitude)
                else altitude - self._ground_amsl_m
            )
        else:
            above_ground = home.alt + altitude
        if not math.isfinite(above_ground) or above_ground <= home.alt:
            return int(mavlink.MAV_RESULT_DENIED)
        flight.lift_off(above_ground)
        if f.takeoff_mode is not None:
            self.mode = f.takeoff_mode
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _mission_start(self, first: int) -> int:
        """MAV_CMD_MISSION_START: AUTO from item ``first`` (0: where it stands)."""
        f = self._flavour
        if self.mode != f.mission:
            if self.change_mode(f.mission) != mavlink.MAV_RESULT_ACCEPTED:
                return int(mavlink.MAV_RESULT_FAILED)
        elif self.auto.complete:
            self.auto.start()
        if first > 0 and not self.auto.set_current(first, running=True):
            return int(mavlink.MAV_RESULT_DENIED)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _on_mission_set_current(self, msg: Any) -> None:
        """The older MISSION_SET_CURRENT has no ACK: MISSION_CURRENT says where the mission
        is."""
        running = self.mode == self._flavour.mission and self.armed
        if not self.auto.set_current(int(msg.seq), running=running):
            self.auto.send_current()  # unchanged: where it still is
