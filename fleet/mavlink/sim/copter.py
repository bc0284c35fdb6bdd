"""The simulated copter itself: its flight, modes and arming, the loop that runs it, and the
wiring of the sub-protocols that live in the sibling modules (see the package's docstring)."""

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

from fleet.geo import Position, distance_m
from fleet.mavlink.endpoint import parse_endpoint
from fleet.mavlink.errors import LinkError
from fleet.mavlink.mission import MissionItem, inclusion_polygons
from fleet.mavlink.modes import Autopilot, custom_mode_of, mode_name, px4_custom_mode
from fleet.mavlink.sim import camera as camera_protocol
from fleet.mavlink.sim import companion as companion_protocol
from fleet.mavlink.sim import telemetry
from fleet.mavlink.sim.auto import MissionRunner
from fleet.mavlink.sim.camera import Camera, Shot
from fleet.mavlink.sim.commands import CommandServer, Outcome, addressee
from fleet.mavlink.sim.companion import Companion, FieldSensors
from fleet.mavlink.sim.fence import (
    LANDING_ACTIONS,
    REPORT_ONLY,
    Fence,
    FenceStatus,
    breach_type,
    fence_names,
)
from fleet.mavlink.sim.flavours import FLAVOURS, initial_params
from fleet.mavlink.sim.guided import Guided
from fleet.mavlink.sim.missions import MissionServer
from fleet.mavlink.sim.params import ParamServer
from fleet.mavlink.sim.telemetry import LOW_BATTERY, Streams
from fleet.mavlink.wire import BAD_DATA, connect, drop_closed_tcp_client, encode_text, mavlink
from fleet.simulation.vehicle import SimVehicle, VehicleSpec

logger = logging.getLogger("cpcc.mavsim")

_SETPOINT_LOSS_S = 1.0  # PX4's COM_OF_LOSS_T default
_SAME_TARGET_M = 1e-3  # a guided target this close to the last one is the same again
_MISSION = mavlink.MAV_MISSION_TYPE_MISSION
_FENCE = mavlink.MAV_MISSION_TYPE_FENCE


class MavSim:
    """A simulated copter on a MAVLink connection. See the package docstring.

    ``connection``: where it listens or sends (``fleet.mavlink.endpoint``), e.g.
    ``udpin:127.0.0.1:14560``. ``spec``/``depot``: the airframe and its home (the vehicle
    starts landed there, disarmed). ``speed``: time acceleration of the flight (0: instant).
    ``system_id``/``component_id``: its MAVLink ids. ``autopilot``: "ardupilot" (ArduCopter)
    or "px4". ``ground_amsl_m``: the ground's altitude above mean sea level (the world is
    flat at the depot's ground). ``battery``: the charge it starts with (0..1).
    ``arm_min_battery``: below this it refuses to arm. ``clock``: the wall clock (injectable).
    ``field_seed``: the seed of the ``SensorField`` its sensors read and its camera sees (the
    platform's own simulated field is seed 0). ``payload``: also be the companion computer
    with the gas sensors (component 191) and the camera (component 100), each with its own
    HEARTBEAT; off by default, as a bare ArduCopter (a plain GCS then hears only the
    autopilot). ``camera_url_host``: where the camera's image server listens (port chosen by
    the OS) and the host its ``file_url`` names.
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
        arm_min_battery: float = LOW_BATTERY,
        clock: Callable[[], float] = time.monotonic,
        name: str = "mavsim",
        field_seed: int = 0,
        payload: bool = False,
        camera_url_host: str = "127.0.0.1",
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
        self.payload = payload
        self.camera_url_host = camera_url_host

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
        # What it is doing: "takeoff", "goto" (a target, then hovering there), "hover" (a
        # mission's hold time), "return" and "approach" (then "landing"), or None (landed or
        # holding where it is).
        self._stage: str | None = None
        self._stage_end_s = 0.0
        self._target: Position | None = None
        self._battery_base = min(1.0, max(0.0, battery))
        self._battery_base_used_s = 0.0
        self._battery_warned = False
        self._battery_failsafe = False
        self._last_setpoint_wall = -math.inf
        self._setpoints: deque[float] = deque(maxlen=8)  # when the last setpoints came (wall)

        # Protocol state.
        self._params = ParamServer(
            initial_params(
                self.flavour, spec, system_id=system_id, battery_capacity_mah=battery_capacity_mah
            ),
            self._send,
            bytewise=self.flavour.bytewise_params,
            on_set=self._on_param_set,
        )
        self._missions = MissionServer(self._send, self._wall, name)
        self._pilot = _Pilot(self)
        self._auto = MissionRunner(
            self._pilot,
            lambda: self._missions.missions.get(_MISSION, ()),
            self._send,
            lambda text: self._text(mavlink.MAV_SEVERITY_INFO, text),
            first_seq=self.flavour.mission_first_seq,
        )
        self._fence = Fence(
            self._params.get,
            lambda: self._missions.missions.get(_FENCE, ()),
            depot,
        )
        self._fence_status = FenceStatus()
        self._guided = Guided(
            self._pilot,
            self._fence,
            mode=self.flavour.follows_targets,
            home=depot,
            ground_amsl_m=ground_amsl_m,
            send=self._send,
            text=self._text,
        )

        # The other components: the companion computer with the gas sensors and the camera,
        # each sending with its own MAVLink sender (component id and sequence numbers).
        self._component_mavs: dict[int, Any] = {}
        self._sensors = FieldSensors(field_seed)
        self._companion = Companion(
            self._sensors,
            lambda build: self._send_as(companion_protocol.COMPONENT_ID, build),
            self._where,
            self._wall,
        )
        self._camera = Camera(
            lambda build: self._send_as(camera_protocol.COMPONENT_ID, build),
            self._shot,
            self._wall,
            seed=field_seed,
            host=camera_url_host,
        )
        self._commands = CommandServer(self._execute, self._send)
        self._payload_commands = {
            camera_protocol.COMPONENT_ID: CommandServer(
                lambda command, p, frame: self._camera.command(command, p),
                lambda build: self._send_as(camera_protocol.COMPONENT_ID, build),
            ),
            # The companion only reports: it says so to any command.
            companion_protocol.COMPONENT_ID: CommandServer(
                lambda command, p, frame: (int(mavlink.MAV_RESULT_UNSUPPORTED), None),
                lambda build: self._send_as(companion_protocol.COMPONENT_ID, build),
            ),
        }
        self._announced: tuple[bool, str] | None = None  # (armed, mode) of the last HEARTBEAT
        self._streams = Streams(
            {
                mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._send_heartbeat,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._send_position,
                mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._send_sys_status,
                mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self._send_battery_status,
                mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._send_home,
                mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._send_extended_state,
                mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
                mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: self._auto.send_current,
                mavlink.MAVLINK_MSG_ID_FENCE_STATUS: self._send_fence_status,
                mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE: self._send_scaled_pressure,
                mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._send_gps_raw,
            },
            self._wall,
        )

        # Test hooks and what the tests read back.
        self._link_cut = False
        self._drops: dict[str, int] = defaultdict(int)
        self._prearm_failure: str | None = None
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

    def serve(self, stop: threading.Event, ready: Callable[[], None] | None = None) -> None:
        """Run in the calling thread until ``stop`` is set (what ``manage.py mavsim`` does);
        ``ready`` is called once the link (and the image server) are open.

        Raises LinkError when the connection cannot be opened.
        """
        self._open()
        if ready is not None:
            ready()
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
            return self._params.value(name)

    def message_interval_s(self, message_id: int) -> float | None:
        """The interval a message is sent at (wall seconds), or None when it is not streamed."""
        with self._lock:
            return self._streams.intervals.get(message_id)

    def commands_seen(self, command: int) -> list[int]:
        """The ``confirmation`` of every COMMAND_LONG of this id received (0 for COMMAND_INT)."""
        with self._lock:
            return list(self._commands.seen.get(command, []))

    def mission_items(
        self, mission_type: int = mavlink.MAV_MISSION_TYPE_FENCE
    ) -> list[MissionItem]:
        """The items of the last complete upload of a mission type (the fence by default)."""
        with self._lock:
            return list(self._missions.missions.get(mission_type, []))

    def fence_polygons(self) -> list[list[tuple[float, float]]]:
        """The inclusion polygons of the uploaded fence, as (lat, lng) vertices."""
        return inclusion_polygons(self.mission_items(mavlink.MAV_MISSION_TYPE_FENCE))

    def mission_current(self) -> int:
        """The mission item AUTO flies (or begins with)."""
        with self._lock:
            return self._auto.current

    def fence_status(self) -> FenceStatus:
        """What FENCE_STATUS reports now (a copy)."""
        with self._lock:
            return replace(self._fence_status)

    def camera_captures(self) -> list[camera_protocol.Capture]:
        """The images taken so far, in order (index, where, when)."""
        return self._camera.captures

    @property
    def camera_port(self) -> int | None:
        """The image server's port while the link is open."""
        return self._camera.port

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
                self._commands.ignored.add(command)
            else:
                self._commands.ignored.discard(command)

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
        self._component_mavs = {
            component: mavlink.MAVLink(self._conn, self.system_id, component)
            for component in (companion_protocol.COMPONENT_ID, camera_protocol.COMPONENT_ID)
        }
        try:
            if self.payload:
                self._camera.open()
        except OSError as exc:
            self._close()
            raise LinkError(f"mavsim cannot serve images: {exc}") from exc
        logger.info(
            "mavsim %s: %s copter on %s (speed %g)",
            self.name,
            self.flavour.autopilot.value,
            self.endpoint,
            self.speed,
        )

    def _close(self) -> None:
        self._camera.close()
        self._component_mavs = {}
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

    def _send_as(self, component: int, build: Callable[[Any], None]) -> None:
        mav = self._component_mavs.get(component)
        if self._link_cut or mav is None:
            return
        build(mav)

    def _text(self, severity: int, text: str) -> None:
        self._texts_sent.append(text)
        logger.info("mavsim %s: %s", self.name, text)
        if self._streams.statustext_on:
            self._send(lambda mav: mav.statustext_send(severity, encode_text(text, 50)))

    def _send_heartbeat(self) -> None:
        self._announced = (self._armed, self._mode)
        autopilot = self.flavour.heartbeat_autopilot
        custom = custom_mode_of(self.flavour.autopilot, self._mode)
        armed, critical = self._armed, self._battery_failsafe
        self._send(
            lambda mav: telemetry.heartbeat(
                mav, autopilot=autopilot, custom_mode=custom, armed=armed, critical=critical
            )
        )

    def _velocity(self, now: float) -> tuple[float, float, float]:
        """North, east, down in m/s: the plan's next simulated tenth of a second."""
        ahead = self._vehicle.position_at(now + 0.1)
        return telemetry.velocity_ned(self._vehicle.position_at(now), ahead, 0.1)

    def _heading_deg(self, now: float) -> float | None:
        """The direction of travel, or None when it hovers or stands."""
        north, east, _ = self._velocity(now)
        if math.hypot(north, east) <= 0.1:
            return None
        return math.degrees(math.atan2(east, north)) % 360

    def _where(self) -> tuple[Position, float]:
        now = self._now()
        return self._vehicle.position_at(now), now

    def _shot(self) -> Shot:
        now = self._now()
        here = self._vehicle.position_at(now)
        return Shot(
            position=here,
            amsl_m=self.ground_amsl_m + here.alt,
            relative_m=here.alt - self.home.alt,
            heading_deg=self._heading_deg(now),
            time_s=now,
        )

    def _send_position(self) -> None:
        now = self._now()
        here = self._vehicle.position_at(now)
        velocity, heading = self._velocity(now), self._heading_deg(now)
        boot_ms = self._boot_ms()
        self._send(
            lambda mav: telemetry.global_position(
                mav,
                boot_ms=boot_ms,
                here=here,
                home=self.home,
                ground_amsl_m=self.ground_amsl_m,
                velocity=velocity,
                heading_deg=heading,
            )
        )

    def _send_sys_status(self) -> None:
        fraction = self._battery(self._now())
        prearm_ok = self._arming_refusal() is None
        on_ground = self._on_ground
        self._send(
            lambda mav: telemetry.sys_status(
                mav, fraction=fraction, prearm_ok=prearm_ok, on_ground=on_ground
            )
        )

    def _send_battery_status(self) -> None:
        fraction = self._battery(self._now())
        on_ground = self._on_ground
        self._send(
            lambda mav: telemetry.battery_status(
                mav,
                fraction=fraction,
                battery_s=self._spec.battery_s,
                capacity_mah=self.battery_capacity_mah,
                on_ground=on_ground,
            )
        )

    def _send_home(self) -> None:
        self._send(
            lambda mav: telemetry.home_position(
                mav, home=self.home, ground_amsl_m=self.ground_amsl_m
            )
        )

    def _send_scaled_pressure(self) -> None:
        # The barometer and thermometer of the default catalog, read from the simulated field.
        here, now = self._where()
        pressure = self._sensors.value("pressure", here, now)
        temperature = self._sensors.value("temperature", here, now)
        boot_ms = self._boot_ms()
        self._send(
            lambda mav: telemetry.scaled_pressure(
                mav, boot_ms=boot_ms, pressure_hpa=pressure, temperature_c=temperature
            )
        )

    def _send_gps_raw(self) -> None:
        # The receiver's own fix, a few metres off the position GLOBAL_POSITION_INT reports.
        here, now = self._where()
        fix = self._sensors.gps(here, now)
        north, east, _ = self._velocity(now)
        heading = self._heading_deg(now)
        boot_ms = self._boot_ms()
        self._send(
            lambda mav: telemetry.gps_raw(
                mav,
                boot_ms=boot_ms,
                fix=fix,
                ground_amsl_m=self.ground_amsl_m,
                speed_mps=math.hypot(north, east),
                heading_deg=heading,
            )
        )

    def _send_fence_status(self) -> None:
        self._send(self._fence_status.send)

    def _send_extended_state(self) -> None:
        if self._on_ground:
            landed = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif self._stage == "takeoff":
            landed = mavlink.MAV_LANDED_STATE_TAKEOFF
        elif self._stage == "landing":
            landed = mavlink.MAV_LANDED_STATE_LANDING
        else:
            landed = mavlink.MAV_LANDED_STATE_IN_AIR
        self._send(lambda mav: telemetry.extended_sys_state(mav, landed_state=landed))

    def _send_autopilot_version(self) -> None:
        bytewise = self.flavour.bytewise_params
        self._send(lambda mav: telemetry.autopilot_version(mav, bytewise_params=bytewise))

    def _boot_ms(self) -> int:
        return int(self._wall() * 1000) & 0xFFFFFFFF

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
        if kind in ("MISSION_ITEM", "MISSION_ITEM_INT") and msg.current == 2:
            # ArduPilot's "guided mode waypoint", not an item of the mission.
            self._guided.on_item(msg, self._reply_to(msg))
            return
        handler = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command,
            "COMMAND_INT": self._on_command,
            "SET_MODE": self._on_set_mode,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_position_target,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_position_target,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "REQUEST_DATA_STREAM": self._streams.on_request_data_stream,
        }.get(kind)
        if handler is not None:
            handler(msg)
        elif not self._params.handle(msg):
            self._missions.handle(msg)

    def _on_heartbeat(self, msg: Any) -> None:
        if msg.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER):
            return
        self._gcs_heartbeats += 1
        source = self._reply_to(msg)
        if source not in self._gcs_seen:
            # A new ground station hears a heartbeat at once instead of within a second.
            self._gcs_seen.add(source)
            self._streams.due_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)

    def _reply_to(self, msg: Any) -> tuple[int, int]:
        return int(msg.get_srcSystem()), int(msg.get_srcComponent())

    # --- commands -------------------------------------------------------------------------

    def _on_command(self, msg: Any) -> None:
        server = self._commands
        if self.payload:
            server = self._payload_commands.get(addressee(msg), server)
        server.handle(msg, self._reply_to(msg))

    def _execute(self, command: int, p: tuple[float, ...], frame: int) -> Outcome:
        """Run a command (``frame``: where its positions are); returns its MAV_RESULT and what
        to send after the ACK, if anything."""
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
            return self._streams.set_interval(round(p[0]), p[1]), None
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            message_id = round(p[0])
            interval = self._streams.intervals.get(message_id)
            interval_us = round(interval * 1e6) if interval is not None else -1
            return accepted, lambda: self._send(
                lambda mav: mav.message_interval_send(message_id, interval_us)
            )
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            sender = self._streams.senders.get(round(p[0]))
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
            self._params.set("FENCE_ENABLE", 1.0 if p[0] >= 0.5 else 0.0)
            return accepted, None
        if command == mavlink.MAV_CMD_DO_REPOSITION:
            return self._guided.reposition(p, frame), None
        if command == mavlink.MAV_CMD_MISSION_START:
            return self._mission_start(round(p[0])), None
        if command == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            running = self._mode == self.flavour.mission and self._armed
            if not self._auto.set_current(round(p[0]), running=running):
                return mavlink.MAV_RESULT_DENIED, None
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
        return f.armable | f.hold | {f.follows_targets, f.rtl, f.land, f.mission}

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
        if mode == f.mission:
            refusal = self._auto.refusal(armed=self._armed)
            if refusal is not None:
                self._text(mavlink.MAV_SEVERITY_WARNING, f"Mode change to {mode} failed: {refusal}")
                return int(mavlink.MAV_RESULT_FAILED)
        now = self._now()
        self._mode = mode
        if mode == f.mission:
            self._auto.start()  # the next tick begins (or resumes) the current item
        if not self._on_ground:
            if mode == f.rtl:
                self._start_return(now)
            elif mode == f.land:
                self._start_landing(now)
            elif mode in f.hold or mode == f.follows_targets:
                self._hold(now)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _mission_start(self, first: int) -> int:
        """MAV_CMD_MISSION_START: AUTO from item ``first`` (0: where it stands)."""
        f = self.flavour
        if self._mode != f.mission:
            if self._change_mode(f.mission) != mavlink.MAV_RESULT_ACCEPTED:
                return int(mavlink.MAV_RESULT_FAILED)
        elif self._auto.complete:
            self._auto.start()
        if first > 0 and not self._auto.set_current(first, running=True):
            return int(mavlink.MAV_RESULT_DENIED)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _on_mission_set_current(self, msg: Any) -> None:
        # The older MISSION_SET_CURRENT has no ACK: MISSION_CURRENT says where the mission is.
        running = self._mode == self.flavour.mission and self._armed
        if not self._auto.set_current(int(msg.seq), running=running):
            self._auto.send_current()  # unchanged: where it still is

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
        self._lift_off(above_ground)
        if f.takeoff_mode is not None:
            self._mode = f.takeoff_mode
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def _lift_off(self, above_ground: float) -> None:
        now = self._now()
        top = self._vehicle.position_at(now).with_alt(above_ground)
        self._on_ground = False
        self._fly(top, "takeoff", now)

    def _fly(self, target: Position, stage: str, now: float) -> None:
        self._target = target
        self._stage = stage
        self._stage_end_s = self._vehicle.fly_to(target, now)

    def _idle(self, now: float) -> bool:
        """No manoeuvre under way: landed, or hovering (a target reached, a wait over)."""
        return self._stage is None or (
            self._stage in ("goto", "hover") and now >= self._stage_end_s
        )

    def _fly_guided(self, target: Position) -> None:
        same = self._target is not None and distance_m(target, self._target) < _SAME_TARGET_M
        if same and self._stage == "goto":
            return  # the same target again (targets are re-sent against packet loss)
        self._fly(target, "goto", self._now())

    def _on_position_target(self, msg: Any) -> None:
        self._setpoints.append(self._wall())  # PX4's offboard mode wants a live stream
        self._last_setpoint_wall = self._wall()
        self._guided.on_position_target(msg)

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
        rtl_alt = self.home.alt + self._params.value(name) * unit
        # As SimVehicle.return_to_depot: cruise home at the current altitude (at least the
        # return altitude), then land vertically.
        above = self.home.with_alt(max(here.alt, rtl_alt, self.home.alt))
        self._target = above
        self._stage = "return"
        self._stage_end_s = self._vehicle.fly_to(above, now)

    def _start_approach(self, spot: Position, now: float) -> None:
        # NAV_LAND at a place: fly there at the altitude it is at, then land.
        here = self._vehicle.position_at(now)
        self._fly(spot.with_alt(here.alt), "approach", now)

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
        if self._stage in ("return", "approach") and now >= self._stage_end_s:
            self._start_landing(self._stage_end_s)
            now = self._now()
        if self._stage == "landing" and now >= self._stage_end_s:
            self._touchdown(self._stage_end_s)
        if self._mode == f.mission:
            self._auto.tick()
            now = self._now()
        self._check_fence(now)
        self._check_battery(now)
        self._check_auto_disarm()
        self._check_setpoint_stream()
        self._missions.tick()
        if self._announced != (self._armed, self._mode):
            # A mode or arming change goes out at once rather than with the next 1 Hz
            # heartbeat (ArduPilot waits for the next one): a GCS that confirms a change by
            # the heartbeat then waits milliseconds, not a second.
            self._send_heartbeat()
            self._streams.sent_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
        self._streams.send_due()
        if self.payload:
            # After the autopilot's messages: a new ground station hears the autopilot first.
            self._companion.tick()
            self._camera.tick()

    def _check_fence(self, now: float) -> None:
        """A fence breach while flying: FENCE_STATUS, "Polygon fence breached" and the
        FENCE_ACTION (ArduCopter's Copter::fence_check)."""
        if not self._armed or self._on_ground or self._stage == "landing":
            return  # ArduCopter never acts on a breach in the final stage of landing either
        status = self._fence_status
        breaches = self._fence.breaches(self._vehicle.position_at(now))
        if breaches == status.breaches:
            return
        new = breaches & ~status.breaches
        status.breaches = breaches
        status.breach_type = breach_type(breaches)
        if new:
            status.count += 1
            status.time_ms = self._boot_ms()
            self._text(mavlink.MAV_SEVERITY_NOTICE, f"{fence_names(new)} breached")
        self._send_fence_status()
        if new:
            self._fence_action()

    def _fence_action(self) -> None:
        f = self.flavour
        action = round(self._params.get("FENCE_ACTION", REPORT_ONLY))
        if action == REPORT_ONLY or self._mode == f.land:
            return
        if action in LANDING_ACTIONS:
            self._change_mode(f.land)
        elif self._mode != f.rtl and self._change_mode(f.rtl) != mavlink.MAV_RESULT_ACCEPTED:
            self._change_mode(f.land)  # RTL or, when that fails, land

    def _check_battery(self, now: float) -> None:
        fraction = self._battery(now)
        if fraction < LOW_BATTERY and not self._battery_warned and not self._on_ground:
            self._battery_warned = True
            self._text(mavlink.MAV_SEVERITY_WARNING, "Battery 1 is low")
        if fraction <= 0.0 and not self._on_ground and self._stage != "landing":
            # ArduPilot's critical battery failsafe: land where it is.
            self._battery_failsafe = True
            self._text(mavlink.MAV_SEVERITY_CRITICAL, "Battery 1 is critical: landing")
            self._mode = self.flavour.land
            self._start_landing(now)

    def _check_auto_disarm(self) -> None:
        delay = self._params.value(self.flavour.disarm_delay_param)
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

    def _on_param_set(self, name: str, value: float) -> None:
        for param_name, field, unit in self.flavour.speed_params:
            if name == param_name and value > 0:
                # A GCS changing the speed changes the kinematics from the next leg on.
                self._spec = replace(self._spec, **{field: value * unit})
                self._vehicle.spec = self._spec


class _Pilot:
    """The copter's flight as AUTO and GUIDED see it (``auto.Flight``, ``guided.Vehicle``)."""

    def __init__(self, sim: MavSim) -> None:
        self._sim = sim

    @property
    def on_ground(self) -> bool:
        return self._sim._on_ground

    @property
    def armed(self) -> bool:
        return self._sim._armed

    @property
    def mode(self) -> str:
        return self._sim._mode

    def change_mode(self, mode: str) -> int:
        return self._sim._change_mode(mode)

    def idle(self) -> bool:
        return self._sim._idle(self._sim._now())

    def here(self) -> Position:
        return self._sim._vehicle.position_at(self._sim._now())

    def item_target(self, item: MissionItem) -> Position:
        here = self.here()
        lat, lng = (here.lat, here.lng) if item.x == 0 and item.y == 0 else (item.lat, item.lng)
        return self._sim._guided.target(item.frame, lat, lng, item.z)

    def climb_to(self, alt: float) -> None:
        sim = self._sim
        if sim._on_ground:
            sim._lift_off(alt)
        else:
            sim._fly(self.here().with_alt(alt), "goto", sim._now())

    def go_to(self, target: Position) -> None:
        self._sim._fly_guided(target)

    def hover_for(self, seconds: float) -> None:
        sim = self._sim
        now = sim._now()
        sim._hold(now)
        # A stage with an end: the instant clock (speed 0) moves on to it as to any other.
        sim._stage = "hover"
        sim._stage_end_s = now + seconds

    def return_home(self) -> None:
        self._sim._start_return(self._sim._now())

    def land_at(self, spot: Position) -> None:
        self._sim._start_approach(spot, self._sim._now())
