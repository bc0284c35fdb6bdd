"""The simulated copter itself: flight, commands, telemetry, parameters (see the package's
docstring)."""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from fleet.geo import Position
from fleet.mavlink import params as param_codec
from fleet.mavlink.endpoint import parse_endpoint
from fleet.mavlink.errors import LinkError
from fleet.mavlink.mission import MissionItem, inclusion_polygons
from fleet.mavlink.modes import Autopilot, custom_mode_of, mode_name, px4_custom_mode
from fleet.mavlink.sim.flavours import FLAVOURS, Param, initial_params
from fleet.mavlink.sim.missions import MissionServer
from fleet.mavlink.wire import BAD_DATA, connect, drop_closed_tcp_client, encode_text, mavlink
from fleet.simulation.vehicle import SimVehicle, VehicleSpec

logger = logging.getLogger("cpcc.mavsim")

_M_PER_DEG = 111_320.0  # metres per degree of latitude (for velocities only)
_CELLS = 4  # a 4S LiPo: 16.8 V full, 14.0 V empty
_CELL_FULL_V = 4.2
_CELL_EMPTY_V = 3.5
_LOW_BATTERY = 0.2
_CRITICAL_BATTERY = 0.1
_SETPOINT_LOSS_S = 1.0  # PX4's COM_OF_LOSS_T default
_POSITION_IGNORE = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
)
_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
)
_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
)


class MavSim:
    """A simulated copter on a MAVLink connection. See the package docstring.

    ``connection``: where it listens or sends (``fleet.mavlink.endpoint``), e.g.
    ``udpin:127.0.0.1:14560``. ``spec``/``depot``: the airframe and its home (the vehicle
    starts landed there, disarmed). ``speed``: time acceleration of the flight (0: instant).
    ``system_id``/``component_id``: its MAVLink ids. ``autopilot``: "ardupilot" (ArduCopter)
    or "px4". ``ground_amsl_m``: the ground's altitude above mean sea level (the world is
    flat at the depot's ground). ``battery``: the charge it starts with (0..1).
    ``arm_min_battery``: below this it refuses to arm. ``clock``: the wall clock (injectable).
    Raises LinkError for a malformed connection string, ValueError for a bad speed.
    """

    def __init__(
        self,
        connection: str,
        *,
        spec: VehicleSpec,
        depot: Position,
        speed: float = 1.0,
        system_id: int = 1,
        component_id: int = mavlink.MAV_COMP_ID_AUTOPILOT1,
        autopilot: str = "ardupilot",
        ground_amsl_m: float = 0.0,
        battery: float = 1.0,
        battery_capacity_mah: int = 5000,
        arm_min_battery: float = _LOW_BATTERY,
        clock: Callable[[], float] = time.monotonic,
        name: str = "mavsim",
    ) -> None:
        if not (math.isfinite(speed) and speed >= 0):
            raise ValueError(f"speed must be a finite number >= 0, got {speed!r}")
        if autopilot not in FLAVOURS:
            raise ValueError(f"autopilot must be one of {sorted(FLAVOURS)}, got {autopilot!r}")
        self.endpoint = parse_endpoint(connection)
        self.flavour = FLAVOURS[autopilot]
        self.name = name
        self.speed = speed
        self.system_id = system_id
        self.component_id = component_id
        self.home = depot
        self.ground_amsl_m = ground_amsl_m
        self.battery_capacity_mah = battery_capacity_mah
        self.arm_min_battery = arm_min_battery
        self.clock = clock

        self._spec = spec
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._conn: Any = None
        self._t0 = clock()
        self._instant_t = 0.0  # speed 0: the simulated clock, moved to each plan's end

        # Flight state, all in simulated seconds.
        self._vehicle = SimVehicle(spec, depot, now_s=0.0)
        self._flown_before_s = 0.0  # flight time of the SimVehicles replaced on touchdown
        self._on_ground = True
        self._armed = False
        self._armed_wall = 0.0
        self._mode = self.flavour.initial_mode
        self._stage: str | None = None  # "takeoff", "goto", "return", "landing"
        self._stage_end_s = 0.0
        self._target: Position | None = None
        self._battery_base = min(1.0, max(0.0, battery))
        self._battery_base_used_s = 0.0
        self._battery_warned = False
        self._battery_failsafe = False
        self._last_setpoint_wall = -math.inf
        self._setpoints: deque[float] = deque(maxlen=8)  # when the last setpoints came (wall)

        # Protocol state.
        self._params: dict[str, Param] = initial_params(
            self.flavour,
            spec,
            system_id=system_id,
            battery_capacity_mah=battery_capacity_mah,
        )
        self._intervals: dict[int, float] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 1.0,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
        }
        self._next_due: dict[int, float] = {}
        self._missions = MissionServer(self._send, self._wall, name)
        self._last_command: tuple[tuple[int, tuple[float, ...]], int] | None = None
        self._statustext_on = True
        self._announced: tuple[bool, str] | None = None  # (armed, mode) of the last HEARTBEAT
        self._streams = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._send_heartbeat,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._send_position,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._send_sys_status,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self._send_battery_status,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._send_home,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._send_extended_state,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
        }

        # Test hooks and what the tests read back.
        self._link_cut = False
        self._ignored: set[int] = set()
        self._drops: dict[str, int] = defaultdict(int)
        self._prearm_failure: str | None = None
        self._commands_seen: dict[int, list[int]] = defaultdict(list)
        self._texts_sent: list[str] = []
        self._gcs_heartbeats = 0
        self._gcs_seen: set[tuple[int, int]] = set()

    # --- life cycle -----------------------------------------------------------------------

    def start(self) -> MavSim:
        """Open the connection and run the simulation in a background thread; returns self.

        Raises LinkError when the connection cannot be opened (a port in use).
        """
        self._open()
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name=f"mavsim {self.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the connection (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._thread = None
        self._close()

    def serve(self, stop: threading.Event) -> None:
        """Run in the calling thread until ``stop`` is set (what ``manage.py mavsim`` does).

        Raises LinkError when the connection cannot be opened.
        """
        self._open()
        self._stop = stop
        try:
            self._loop()
        finally:
            self._close()

    def __enter__(self) -> MavSim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- what tests and the command read --------------------------------------------------

    def sim_now(self) -> float:
        """The simulated clock, in seconds since the simulator started."""
        with self._lock:
            return self._now()

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def mode(self) -> str:
        """The flight mode's name ("GUIDED", "RTL", ... or PX4's "OFFBOARD", "AUTO.RTL")."""
        return self._mode

    @property
    def on_ground(self) -> bool:
        return self._on_ground

    def position(self) -> Position:
        """Where the vehicle is now (altitude above ground, like the platform's positions)."""
        with self._lock:
            return self._vehicle.position_at(self._now())

    def battery_fraction(self) -> float:
        """The battery's charge now, 0..1."""
        with self._lock:
            return self._battery(self._now())

    def flight_s(self) -> float:
        """Simulated seconds flown since the simulator started."""
        with self._lock:
            return self._used_s(self._now())

    def param(self, name: str) -> float:
        """A parameter's value. Raises KeyError for an unknown name."""
        with self._lock:
            return self._params[name].value

    def message_interval_s(self, message_id: int) -> float | None:
        """The interval a message is sent at (wall seconds), or None when it is not streamed."""
        with self._lock:
            return self._intervals.get(message_id)

    def commands_seen(self, command: int) -> list[int]:
        """The ``confirmation`` of every COMMAND_LONG of this id received (0 for COMMAND_INT)."""
        with self._lock:
            return list(self._commands_seen.get(command, []))

    def mission_items(
        self, mission_type: int = mavlink.MAV_MISSION_TYPE_FENCE
    ) -> list[MissionItem]:
        """The items of the last complete upload of a mission type (the fence by default)."""
        with self._lock:
            return list(self._missions.missions.get(mission_type, []))

    def fence_polygons(self) -> list[list[tuple[float, float]]]:
        """The inclusion polygons of the uploaded fence, as (lat, lng) vertices."""
        return inclusion_polygons(self.mission_items(mavlink.MAV_MISSION_TYPE_FENCE))

    def texts_sent(self) -> list[str]:
        """Every STATUSTEXT sent, oldest first."""
        with self._lock:
            return list(self._texts_sent)

    @property
    def gcs_heartbeats(self) -> int:
        """How many heartbeats it has received from ground stations or companions."""
        return self._gcs_heartbeats

    # --- test hooks ---------------------------------------------------------------------

    def cut_link(self) -> None:
        """Go silent and deaf, as if the radio died: nothing is sent, everything is dropped.

        The vehicle keeps flying what it was told.
        """
        with self._lock:
            self._link_cut = True

    def restore_link(self) -> None:
        with self._lock:
            self._link_cut = False

    def ignore_command(self, command: int, ignore: bool = True) -> None:
        """Never acknowledge (nor execute) a command id; ``commands_seen`` still counts it."""
        with self._lock:
            if ignore:
                self._ignored.add(command)
            else:
                self._ignored.discard(command)

    def drop_incoming(self, msg_type: str, count: int = 1) -> None:
        """Lose the next ``count`` received messages of a type, e.g. "MISSION_COUNT"."""
        with self._lock:
            self._drops[msg_type] += count

    def set_battery(self, fraction: float) -> None:
        """Set the battery's charge now (0..1), as a swap would."""
        with self._lock:
            self._reset_battery(fraction)

    def fail_prearm(self, reason: str | None) -> None:
        """Make arming fail with this reason (a STATUSTEXT "PreArm: <reason>"), or stop."""
        with self._lock:
            self._prearm_failure = reason

    # --- the loop ---------------------------------------------------------------------------

    def _open(self) -> None:
        try:
            self._conn = connect(
                self.endpoint.pymavlink_device,
                baud=self.endpoint.baud,
                source_system=self.system_id,
                source_component=self.component_id,
            )
        except ImportError as exc:
            raise LinkError(f"{self.endpoint}: serial links need pyserial ({exc})") from exc
        except (OSError, ValueError) as exc:
            raise LinkError(f"mavsim cannot open {self.endpoint}: {exc}") from exc
        logger.info(
            "mavsim %s: %s copter on %s (speed %g)",
            self.name,
            self.flavour.autopilot.value,
            self.endpoint,
            self.speed,
        )

    def _close(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def _loop(self) -> None:
        conn = self._conn
        while not self._stop.is_set():
            try:
                # A short wait keeps the message rates (up to 100 Hz) and the flight's
                # events (take-off done, touchdown) within a hundredth of a second.
                msg = conn.recv_match(blocking=True, timeout=0.01)
                if msg is None:
                    drop_closed_tcp_client(conn)
                with self._lock:
                    if msg is not None:
                        self._receive(msg)
                    self._tick()
            except Exception:
                if self._stop.is_set():
                    return
                logger.exception("mavsim %s", self.name)
                self._stop.wait(0.2)

    def _now(self) -> float:
        if self.speed > 0:
            return (self.clock() - self._t0) * self.speed
        # Instant flights: the simulated clock stands at the end of whatever is planned.
        plan_end = self._vehicle.plan_end_s
        if self._stage is not None:
            plan_end = max(plan_end, self._stage_end_s)
        self._instant_t = max(self._instant_t, plan_end)
        return self._instant_t

    def _wall(self) -> float:
        return self.clock() - self._t0

    # --- sending --------------------------------------------------------------------------

    def _send(self, build: Callable[[Any], None]) -> None:
        if self._link_cut or self._conn is None:
            return
        build(self._conn.mav)

    def _text(self, severity: int, text: str) -> None:
        self._texts_sent.append(text)
        logger.info("mavsim %s: %s", self.name, text)
        if self._statustext_on:
            self._send(lambda mav: mav.statustext_send(severity, encode_text(text, 50)))

    def _send_heartbeat(self) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self._armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if self._battery_failsafe:
            status = mavlink.MAV_STATE_CRITICAL
        else:
            status = mavlink.MAV_STATE_ACTIVE if self._armed else mavlink.MAV_STATE_STANDBY
        custom = custom_mode_of(self.flavour.autopilot, self._mode)
        self._announced = (self._armed, self._mode)
        self._send(
            lambda mav: mav.heartbeat_send(
                mavlink.MAV_TYPE_QUADROTOR, self.flavour.heartbeat_autopilot, base, custom, status
            )
        )

    def _send_position(self) -> None:
        now = self._now()
        here = self._vehicle.position_at(now)
        # Velocity over the next simulated tenth of a second of the plan (NED, cm/s).
        ahead = self._vehicle.position_at(now + 0.1)
        north = (ahead.lat - here.lat) * _M_PER_DEG / 0.1
        east = (ahead.lng - here.lng) * _M_PER_DEG * math.cos(math.radians(here.lat)) / 0.1
        down = -(ahead.alt - here.alt) / 0.1
        heading = 65535  # UINT16_MAX: unknown
        if math.hypot(north, east) > 0.1:
            heading = round(math.degrees(math.atan2(east, north)) % 360 * 100) % 36000
        self._send(
            lambda mav: mav.global_position_int_send(
                self._boot_ms(),
                round(here.lat * 1e7),
                round(here.lng * 1e7),
                round((self.ground_amsl_m + here.alt) * 1000),
                round((here.alt - self.home.alt) * 1000),
                _clamp16(north * 100),
                _clamp16(east * 100),
                _clamp16(down * 100),
                heading,
            )
        )

    def _send_sys_status(self) -> None:
        fraction = self._battery(self._now())
        health = _SENSORS
        if self._arming_refusal() is None:
            health |= mavlink.MAV_SYS_STATUS_PREARM_CHECK
        present = _SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK
        self._send(
            lambda mav: mav.sys_status_send(
                present,
                present,
                health,
                200,  # load, per mille
                self._voltage_mv(fraction),
                self._current_ca(),
                round(fraction * 100),
                0,
                0,
                0,
                0,
                0,
                0,
            )
        )

    def _send_battery_status(self) -> None:
        fraction = self._battery(self._now())
        if fraction <= 0.0:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY
        elif fraction < _CRITICAL_BATTERY:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
        elif fraction < _LOW_BATTERY:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_LOW
        else:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_OK
        battery_s = self._spec.battery_s
        remaining_s = round(fraction * battery_s) if battery_s is not None else 0
        cell_mv = self._voltage_mv(fraction) // _CELLS
        # Per-cell voltages, the unused cells UINT16_MAX as the message asks.
        cells = [cell_mv] * _CELLS + [65535] * (10 - _CELLS)
        self._send(
            lambda mav: mav.battery_status_send(
                0,
                mavlink.MAV_BATTERY_FUNCTION_ALL,
                mavlink.MAV_BATTERY_TYPE_LIPO,
                32767,  # INT16_MAX: temperature unknown
                cells,
                self._current_ca(),
                round((1.0 - fraction) * self.battery_capacity_mah),
                -1,  # energy consumed: unknown
                round(fraction * 100),
                remaining_s,
                state,
            )
        )

    def _send_home(self) -> None:
        self._send(
            lambda mav: mav.home_position_send(
                round(self.home.lat * 1e7),
                round(self.home.lng * 1e7),
                round((self.ground_amsl_m + self.home.alt) * 1000),
                0.0,
                0.0,
                0.0,
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
            )
        )

    def _send_extended_state(self) -> None:
        if self._on_ground:
            landed = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif self._stage == "takeoff":
            landed = mavlink.MAV_LANDED_STATE_TAKEOFF
        elif self._stage == "landing":
            landed = mavlink.MAV_LANDED_STATE_LANDING
        else:
            landed = mavlink.MAV_LANDED_STATE_IN_AIR
        self._send(
            lambda mav: mav.extended_sys_state_send(mavlink.MAV_VTOL_STATE_UNDEFINED, landed)
        )

    def _send_autopilot_version(self) -> None:
        capabilities = _CAPABILITIES | (
            mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
            if self.flavour.bytewise_params
            else mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
        )
        version = 4 << 24 | 5 << 16 | 0 << 8 | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL
        self._send(
            lambda mav: mav.autopilot_version_send(
                capabilities, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0
            )
        )

    def _boot_ms(self) -> int:
        return int(self._wall() * 1000) & 0xFFFFFFFF

    def _voltage_mv(self, fraction: float) -> int:
        cell = _CELL_EMPTY_V + (_CELL_FULL_V - _CELL_EMPTY_V) * fraction
        return round(cell * _CELLS * 1000)

    def _current_ca(self) -> int:
        return 50 if self._on_ground else 1500  # 0.5 A idle, 15 A hovering or cruising

    # --- receiving ------------------------------------------------------------------------

    def _receive(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == BAD_DATA or self._link_cut:
            return
        if self._drops.get(kind, 0) > 0:
            self._drops[kind] -= 1
            return
        if getattr(msg, "target_system", 0) not in (0, self.system_id):
            return  # addressed to another vehicle
        handler = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command,
            "COMMAND_INT": self._on_command,
            "SET_MODE": self._on_set_mode,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_position_target,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
        }.get(kind)
        if handler is not None:
            handler(msg)
        else:
            self._missions.handle(msg)

    def _on_heartbeat(self, msg: Any) -> None:
        if msg.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER):
            return
        self._gcs_heartbeats += 1
        source = self._reply_to(msg)
        if source not in self._gcs_seen:
            # A new ground station hears a heartbeat at once instead of within a second.
            self._gcs_seen.add(source)
            self._next_due[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = self._wall()

    def _reply_to(self, msg: Any) -> tuple[int, int]:
        return int(msg.get_srcSystem()), int(msg.get_srcComponent())

    # --- commands -------------------------------------------------------------------------

    def _on_command(self, msg: Any) -> None:
        command = int(msg.command)
        is_int = msg.get_type() == "COMMAND_INT"
        confirmation = 0 if is_int else int(msg.confirmation)
        self._commands_seen[command].append(confirmation)
        if command in self._ignored:
            return
        if is_int:
            # COMMAND_INT carries positions in x/y (degrees * 1e7) where COMMAND_LONG has
            # param5/param6; both end up as the same seven numbers here.
            values = (
                msg.param1,
                msg.param2,
                msg.param3,
                msg.param4,
                msg.x / 1e7,
                msg.y / 1e7,
                msg.z,
            )
        else:
            values = (
                msg.param1,
                msg.param2,
                msg.param3,
                msg.param4,
                msg.param5,
                msg.param6,
                msg.param7,
            )
        key = (command, tuple(float(v) for v in values))
        after: Callable[[], None] | None = None
        if confirmation > 0 and self._last_command is not None and self._last_command[0] == key:
            # A retransmission of the command just executed (its ACK was lost): answer again
            # without doing it twice, which is what the confirmation counter is for.
            result = self._last_command[1]
        else:
            result, after = self._execute(command, key[1])
        self._last_command = (key, result)
        system, component = self._reply_to(msg)
        self._send(lambda mav: mav.command_ack_send(command, result, 0, 0, system, component))
        if after is not None:
            after()

    def _execute(self, command: int, p: tuple[float, ...]) -> tuple[int, Callable[[], None] | None]:
        """Run a command; returns its MAV_RESULT and what to send after the ACK, if anything."""
        accepted = mavlink.MAV_RESULT_ACCEPTED
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                return self._arm(), None
            return self._disarm(force=round(p[1]) == 21196), None
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            return self._set_mode_command(p), None
        if command == mavlink.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6]), None
        if command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._change_mode(self.flavour.rtl), None
        if command == mavlink.MAV_CMD_NAV_LAND:
            return self._change_mode(self.flavour.land), None
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(round(p[0]), p[1]), None
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            message_id = round(p[0])
            interval = self._intervals.get(message_id)
            interval_us = round(interval * 1e6) if interval is not None else -1
            return accepted, lambda: self._send(
                lambda mav: mav.message_interval_send(message_id, interval_us)
            )
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            sender = self._streams.get(round(p[0]))
            if sender is None:
                return mavlink.MAV_RESULT_DENIED, None
            return accepted, sender
        if command == mavlink.MAV_CMD_GET_HOME_POSITION:
            return accepted, self._send_home
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return accepted, self._send_autopilot_version
        if command == mavlink.MAV_CMD_DO_FENCE_ENABLE:
            if "FENCE_ENABLE" not in self._params:
                return mavlink.MAV_RESULT_UNSUPPORTED, None
            self._params["FENCE_ENABLE"].value = 1.0 if p[0] >= 0.5 else 0.0
            return accepted, None
        if command == mavlink.MAV_CMD_BATTERY_RESET:
            # ArduPilot's "a fresh battery is in": param2 is its charge in percent.
            self._reset_battery(min(100.0, max(0.0, p[1])) / 100.0)
            return accepted, None
        return mavlink.MAV_RESULT_UNSUPPORTED, None

    # --- arming, modes, flight ------------------------------------------------------------

    def _arming_refusal(self) -> str | None:
        """Why arming would be refused now, or None."""
        if self._prearm_failure is not None:
            return self._prearm_failure
        if self._mode not in self.flavour.armable:
            return "Mode not armable"
        if self._battery(self._now()) < self.arm_min_battery:
            return "Battery 1 below minimum arming capacity"
        return None

    def _arm(self) -> int:
        if self._armed:
            return int(mavlink.MAV_RESULT_ACCEPTED)
        refusal = self._arming_refusal()
        if refusal is not None:
            # ArduPilot tells why in a STATUSTEXT before it answers the command.
            self._text(mavlink.MAV_SEVERITY_CRITICAL, self.flavour.refusal_prefix + refusal)
            return int(mavlink.MAV_RESULT_DENIED)
        self._armed = True
        self._armed_wall = self._wall()
        self._text(mavlink.MAV_SEVERITY_INFO, "Arming motors")
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _disarm(self, *, force: bool) -> int:
        if not self._armed:
            return int(mavlink.MAV_RESULT_ACCEPTED)
        if not self._on_ground:
            if not force:
                self._text(mavlink.MAV_SEVERITY_CRITICAL, "Disarm: vehicle is flying")
                return int(mavlink.MAV_RESULT_FAILED)
            # Forced disarm in the air: the motors stop and the copter drops where it is.
            self._touchdown(self._now(), auto_disarm=False)
        self._armed = False
        self._text(mavlink.MAV_SEVERITY_INFO, "Disarming motors")
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _set_mode_command(self, p: tuple[float, ...]) -> int:
        if not round(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return int(mavlink.MAV_RESULT_UNSUPPORTED)
        if self.flavour.autopilot is Autopilot.PX4:
            custom = px4_custom_mode(round(p[1]), round(p[2]))
        else:
            custom = round(p[1])
        return self._change_mode(mode_name(self.flavour.autopilot, custom))

    def _on_set_mode(self, msg: Any) -> None:
        # The deprecated SET_MODE message: ArduPilot answers it with a COMMAND_ACK whose
        # command is the message's id.
        if not msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return
        result = self._change_mode(mode_name(self.flavour.autopilot, int(msg.custom_mode)))
        system, component = self._reply_to(msg)
        self._send(
            lambda mav: mav.command_ack_send(
                mavlink.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, system, component
            )
        )

    def _supported_modes(self) -> frozenset[str]:
        f = self.flavour
        return f.armable | f.hold | {f.follows_targets, f.rtl, f.land}

    def _change_mode(self, mode: str) -> int:
        """Switch to a mode (a name); returns the MAV_RESULT."""
        f = self.flavour
        if mode not in self._supported_modes():
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Mode change to {mode} failed")
            return int(mavlink.MAV_RESULT_FAILED)
        if mode == f.follows_targets and f.setpoint_stream and not self._setpoints_live():
            # PX4 enters offboard only while setpoints are already streaming.
            self._text(mavlink.MAV_SEVERITY_WARNING, "Offboard: no setpoint stream")
            return int(mavlink.MAV_RESULT_DENIED)
        if mode == self._mode:
            return int(mavlink.MAV_RESULT_ACCEPTED)
        now = self._now()
        self._mode = mode
        if not self._on_ground:
            if mode == f.rtl:
                self._start_return(now)
            elif mode == f.land:
                self._start_landing(now)
            elif mode in f.hold or mode == f.follows_targets:
                self._hold(now)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _takeoff(self, altitude: float) -> int:
        f = self.flavour
        if not self._armed or not self._on_ground:
            return int(mavlink.MAV_RESULT_FAILED)
        if f.takeoff_in is not None and self._mode not in f.takeoff_in:
            return int(mavlink.MAV_RESULT_FAILED)
        if f.takeoff_alt_amsl:
            # PX4: param7 is AMSL; NaN means "the default take-off altitude".
            above_ground = (
                self.home.alt + self._spec.takeoff_alt_m
                if math.isnan(altitude)
                else altitude - self.ground_amsl_m
            )
        else:
            above_ground = self.home.alt + altitude
        if not math.isfinite(above_ground) or above_ground <= self.home.alt:
            return int(mavlink.MAV_RESULT_DENIED)
        now = self._now()
        here = self._vehicle.position_at(now)
        top = here.with_alt(above_ground)
        self._on_ground = False
        self._target = top
        self._stage = "takeoff"
        self._stage_end_s = self._vehicle.fly_to(top, now)
        if f.takeoff_mode is not None:
            self._mode = f.takeoff_mode
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _on_position_target(self, msg: Any) -> None:
        f = self.flavour
        self._setpoints.append(self._wall())
        self._last_setpoint_wall = self._wall()
        if msg.type_mask & _POSITION_IGNORE:
            return  # velocity or acceleration targets: not simulated
        if self._mode != f.follows_targets or not self._armed or self._on_ground:
            return  # ArduCopter ignores targets outside GUIDED and before take-off
        frame = int(msg.coordinate_frame)
        if frame in (
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        ):
            alt = self.home.alt + float(msg.alt)
        elif frame in (mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL):
            alt = float(msg.alt) - self.ground_amsl_m
        elif frame in (
            mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
            mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        ):
            alt = float(msg.alt)  # flat world: above terrain is above ground
        else:
            return
        try:
            target = Position(msg.lat_int / 1e7, msg.lon_int / 1e7, alt)
        except ValueError:
            return
        if target == self._target and self._stage == "goto":
            return  # the same target again (targets are re-sent against packet loss)
        now = self._now()
        self._target = target
        self._stage = "goto"
        self._stage_end_s = self._vehicle.fly_to(target, now)

    def _setpoints_live(self) -> bool:
        wall = self._wall()
        return sum(1 for t in self._setpoints if wall - t <= _SETPOINT_LOSS_S) >= 2

    def _hold(self, now: float) -> None:
        here = self._vehicle.position_at(now)
        self._vehicle.fly_to(here, now)
        self._target = here
        self._stage = None

    def _start_return(self, now: float) -> None:
        here = self._vehicle.position_at(now)
        name, unit = self.flavour.rtl_alt_param
        rtl_alt = self.home.alt + self._params[name].value * unit
        # As SimVehicle.return_to_depot: cruise home at the current altitude (at least the
        # return altitude), then land vertically.
        above = self.home.with_alt(max(here.alt, rtl_alt, self.home.alt))
        self._target = above
        self._stage = "return"
        self._stage_end_s = self._vehicle.fly_to(above, now)

    def _start_landing(self, now: float) -> None:
        here = self._vehicle.position_at(now)
        ground = here.with_alt(self.home.alt)
        self._target = ground
        self._stage = "landing"
        self._stage_end_s = self._vehicle.fly_to(ground, now)

    def _touchdown(self, at: float, *, auto_disarm: bool = True) -> None:
        """On the ground at ``at``: the flight's SimVehicle is retired, a new one stands here."""
        spot = self._vehicle.position_at(at)
        spot = spot.with_alt(self.home.alt)
        self._flown_before_s += self._vehicle.flight_s(at)
        self._vehicle = SimVehicle(self._spec, spot, now_s=at)
        self._on_ground = True
        self._stage = None
        self._target = None
        if auto_disarm and self._armed:
            # ArduCopter disarms by itself once landed.
            self._armed = False
            self._text(mavlink.MAV_SEVERITY_INFO, "Disarming motors")

    # --- the clock ticks ------------------------------------------------------------------

    def _tick(self) -> None:
        now = self._now()
        f = self.flavour
        if self._stage == "takeoff" and now >= self._stage_end_s:
            self._stage = None
            if f.after_takeoff is not None and self._mode == f.takeoff_mode:
                self._mode = f.after_takeoff
        if self._stage == "return" and now >= self._stage_end_s:
            self._start_landing(self._stage_end_s)
            now = self._now()
        if self._stage == "landing" and now >= self._stage_end_s:
            self._touchdown(self._stage_end_s)
        self._check_battery(now)
        self._check_auto_disarm()
        self._check_setpoint_stream()
        self._missions.tick()
        if self._announced != (self._armed, self._mode):
            # A mode or arming change goes out at once rather than with the next 1 Hz
            # heartbeat (ArduPilot waits for the next one): a GCS that confirms a change by
            # the heartbeat then waits milliseconds, not a second.
            self._send_heartbeat()
            self._next_due[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = self._wall() + self._intervals.get(
                mavlink.MAVLINK_MSG_ID_HEARTBEAT, 1.0
            )
        self._send_due()

    def _check_battery(self, now: float) -> None:
        fraction = self._battery(now)
        if fraction < _LOW_BATTERY and not self._battery_warned and not self._on_ground:
            self._battery_warned = True
            self._text(mavlink.MAV_SEVERITY_WARNING, "Battery 1 is low")
        if fraction <= 0.0 and not self._on_ground and self._stage != "landing":
            # ArduPilot's critical battery failsafe: land where it is.
            self._battery_failsafe = True
            self._text(mavlink.MAV_SEVERITY_CRITICAL, "Battery 1 is critical: landing")
            self._mode = self.flavour.land
            self._start_landing(now)

    def _check_auto_disarm(self) -> None:
        delay = self._params[self.flavour.disarm_delay_param].value
        if (
            self._armed
            and self._on_ground
            and delay > 0
            and self._wall() - self._armed_wall > delay
        ):
            # Armed on the ground without taking off: disarm after the delay, as ArduPilot
            # does (DISARM_DELAY, wall-clock seconds: a safety timer, not flight time).
            self._armed = False
            self._text(mavlink.MAV_SEVERITY_INFO, "Disarming motors")

    def _check_setpoint_stream(self) -> None:
        f = self.flavour
        if not f.setpoint_stream or self._mode != f.follows_targets:
            return
        if self._wall() - self._last_setpoint_wall > _SETPOINT_LOSS_S:
            # PX4 leaves offboard when the setpoints stop (COM_OF_LOSS_T) and holds.
            self._text(mavlink.MAV_SEVERITY_WARNING, "Offboard lost: holding position")
            self._change_mode("AUTO.LOITER")

    def _send_due(self) -> None:
        wall = self._wall()
        for message_id, interval in list(self._intervals.items()):
            sender = self._streams.get(message_id)
            if sender is None:
                continue
            due = self._next_due.get(message_id, wall)
            if wall >= due:
                sender()
                # Keep the cadence, but never try to catch up a backlog.
                self._next_due[message_id] = max(due + interval, wall)

    def _set_interval(self, message_id: int, interval_us: float) -> int:
        if message_id == mavlink.MAVLINK_MSG_ID_STATUSTEXT:
            # STATUSTEXT is sent when there is something to say; -1 silences it.
            self._statustext_on = interval_us >= 0
            return int(mavlink.MAV_RESULT_ACCEPTED)
        if message_id not in self._streams:
            return int(mavlink.MAV_RESULT_DENIED)
        if interval_us < 0:
            self._intervals.pop(message_id, None)
        elif interval_us == 0:
            # 0: the default rate (what it streams at start, otherwise off).
            if message_id in (
                mavlink.MAVLINK_MSG_ID_HEARTBEAT,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                mavlink.MAVLINK_MSG_ID_SYS_STATUS,
            ):
                self._intervals[message_id] = 1.0
            else:
                self._intervals.pop(message_id, None)
        else:
            self._intervals[message_id] = max(interval_us / 1e6, 0.005)
        self._next_due.pop(message_id, None)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _on_request_data_stream(self, msg: Any) -> None:
        # The older rate interface MAVProxy and QGroundControl still use with ArduPilot.
        streams = {
            mavlink.MAV_DATA_STREAM_POSITION: [mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT],
            mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: [
                mavlink.MAVLINK_MSG_ID_SYS_STATUS,
                mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,
                mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
            ],
        }
        if msg.req_stream_id == mavlink.MAV_DATA_STREAM_ALL:
            ids = [i for group in streams.values() for i in group]
        else:
            ids = streams.get(msg.req_stream_id, [])
        rate = float(msg.req_message_rate)
        for message_id in ids:
            interval_us = 1e6 / rate if msg.start_stop and rate > 0 else -1.0
            self._set_interval(message_id, interval_us)

    # --- battery --------------------------------------------------------------------------

    def _used_s(self, now: float) -> float:
        return self._flown_before_s + self._vehicle.flight_s(now)

    def _battery(self, now: float) -> float:
        battery_s = self._spec.battery_s
        if battery_s is None:
            return self._battery_base
        drained = (self._used_s(now) - self._battery_base_used_s) / battery_s
        return min(1.0, max(0.0, self._battery_base - drained))

    def _reset_battery(self, fraction: float) -> None:
        self._battery_base = min(1.0, max(0.0, fraction))
        self._battery_base_used_s = self._used_s(self._now())
        self._battery_warned = False
        self._battery_failsafe = False

    # --- parameters -----------------------------------------------------------------------

    def _send_param(self, name: str) -> None:
        names = list(self._params)
        param = self._params[name]
        wire = param_codec.encode(param.value, param.type, bytewise=self.flavour.bytewise_params)
        self._send(
            lambda mav: mav.param_value_send(
                encode_text(name, 16), wire, param.type, len(names), names.index(name)
            )
        )

    def _on_param_request_list(self, msg: Any) -> None:
        for name in self._params:
            self._send_param(name)

    def _on_param_request_read(self, msg: Any) -> None:
        names = list(self._params)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._send_param(names[msg.param_index])
        elif msg.param_id in self._params:
            self._send_param(msg.param_id)
        # An unknown parameter gets no answer, as on ArduPilot.

    def _on_param_set(self, msg: Any) -> None:
        name = str(msg.param_id)
        param = self._params.get(name)
        if param is None:
            return
        value = param_codec.decode(
            float(msg.param_value), param.type, bytewise=self.flavour.bytewise_params
        )
        if not math.isfinite(value):
            self._send_param(name)  # refused: the echo shows the value kept
            return
        if param_codec.is_integer_type(param.type):
            value = float(round(value))
        param.value = value
        for param_name, field, unit in self.flavour.speed_params:
            if name == param_name and value > 0:
                # A GCS changing the speed changes the kinematics from the next leg on.
                self._spec = replace(self._spec, **{field: value * unit})
                self._vehicle.spec = self._spec
        self._send_param(name)


def _clamp16(value: float) -> int:
    return max(-32768, min(32767, round(value)))
