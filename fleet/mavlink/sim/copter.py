"""The simulated vehicle (a copter unless told otherwise): ``MavSim`` wires the parts that live in the sibling modules (see the
package's docstring), runs them in its loop and is what tests and ``manage.py mavsim`` use."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from fleet.geo import Position
from fleet.mavlink.endpoint import parse_endpoint
from fleet.mavlink.errors import LinkError
from fleet.mavlink.mission import MissionItem, inclusion_polygons
from fleet.mavlink.sim import camera as camera_protocol
from fleet.mavlink.sim.commands import Commander, CommandServer, Outcome
from fleet.mavlink.sim.companion import FieldSensors
from fleet.mavlink.sim.failsafes import Failsafes
from fleet.mavlink.sim.fence import Fence, FenceStatus
from fleet.mavlink.sim.flavours import flavour_of, initial_params
from fleet.mavlink.sim.flight import Flight
from fleet.mavlink.sim.messages import LOW_BATTERY
from fleet.mavlink.sim.missions import MissionServer
from fleet.mavlink.sim.params import ParamServer
from fleet.mavlink.sim.payload import Payload
from fleet.mavlink.sim.telemetry import Telemetry
from fleet.mavlink.sim.transport import Transport, reply_to
from fleet.mavlink.wire import encode_text, mavlink
from fleet.simulation.vehicle import VehicleSpec

logger = logging.getLogger("cpcc.mavsim")

_MISSION = mavlink.MAV_MISSION_TYPE_MISSION
_FENCE = mavlink.MAV_MISSION_TYPE_FENCE


class MavSim:
    """A simulated vehicle on a MAVLink connection. See the package docstring.

    ``connection``: where it listens or sends (``fleet.mavlink.endpoint``), e.g.
    ``udpin:127.0.0.1:14560``. ``spec``/``depot``: the airframe and its home (the vehicle
    starts landed there, disarmed). ``speed``: time acceleration of the flight (0: instant).
    ``system_id``/``component_id``: its MAVLink ids. ``autopilot``: "ardupilot" (ArduCopter)
    or "px4". ``frame``: "copter" (the default), "rover", "boat" (ArduRover) or "sub"
    (ArduSub; ArduPilot only): its HEARTBEAT type, modes and commands, and how it moves (the
    ``spec``'s kind is set to the frame's). ``ground_amsl_m``: the ground's altitude above mean sea level (the world is
    flat at the depot's ground). ``battery``: the charge it starts with (0..1).
    ``arm_min_battery``: below this it refuses to arm. ``clock``: the wall clock (injectable).
    ``field_seed``: the seed of the ``SensorField`` its sensors read and its camera sees (the
    platform's own simulated field is seed 0). ``payload``: also be the companion computer
    with the gas sensors (component 191) and the camera (component 100), each with its own
    HEARTBEAT; off by default, as a bare ArduCopter (a plain GCS then hears only the
    autopilot). ``camera_url_host``: where the camera's image server listens (port chosen by
    the OS) and the host its ``file_url`` names.
    Raises LinkError for a malformed connection string, ValueError for a bad speed, autopilot
    or frame.
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
        frame: str = "copter",
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
        self.flavour = flavour_of(autopilot, frame)
        if spec.kind != self.flavour.kind:
            spec = replace(spec, kind=self.flavour.kind)
        self.endpoint = parse_endpoint(connection)
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

        self._lock = threading.RLock()
        self._t0 = clock()
        self._texts_sent: list[str] = []

        # The link, and the autopilot's flight, modes and protocols over it; with ``payload``,
        # the companion computer and the camera too.
        self._transport = Transport(
            self.endpoint,
            system_id=system_id,
            component_id=component_id,
            components=Payload.COMPONENT_IDS,
            name=name,
        )
        send = self._transport.send
        self._flight = Flight(
            spec,
            depot,
            speed=speed,
            wall=self._wall,
            battery=battery,
            return_alt=self._return_alt,
        )
        self._params = ParamServer(
            initial_params(
                self.flavour, spec, system_id=system_id, battery_capacity_mah=battery_capacity_mah
            ),
            send,
            bytewise=self.flavour.bytewise_params,
            speeds=self.flavour.speed_params,
            on_speed=self._flight.set_speed,
        )
        self._missions = MissionServer(send, self._wall, name)
        fence = Fence(self._params.get, lambda: self._missions.missions.get(_FENCE, ()), depot)
        self._commander = Commander(
            self._flight,
            self._params,
            fence,
            lambda: self._missions.missions.get(_MISSION, ()),
            flavour=self.flavour,
            ground_amsl_m=ground_amsl_m,
            arm_min_battery=arm_min_battery,
            send=send,
            text=self._text,
            wall=self._wall,
            log=lambda line: logger.info("mavsim %s: %s", name, line),
        )
        self._failsafes = Failsafes(
            self._commander,
            self._flight,
            fence,
            self._params,
            flavour=self.flavour,
            send=send,
            text=self._text,
            wall=self._wall,
            gcs_seen=lambda: self._telemetry.gcs_seen_wall,
        )
        sensors = FieldSensors(field_seed)
        self._telemetry = Telemetry(
            self._commander,
            self._flight,
            sensors,
            self._failsafes.fence_status,
            flavour=self.flavour,
            ground_amsl_m=ground_amsl_m,
            capacity_mah=battery_capacity_mah,
            mission_current=self._commander.auto.send_current,
            send=send,
            wall=self._wall,
        )
        self._commands = CommandServer(self._execute, send)
        self._payload = Payload(
            self._transport.sender,
            sensors,
            self._flight.where,
            self._telemetry.shot,
            self._wall,
            seed=field_seed,
            host=camera_url_host,
        )

    # --- life cycle -----------------------------------------------------------------------

    def start(self) -> MavSim:
        """Open the connection and run the simulation in a background thread; returns self.

        Raises LinkError when the connection cannot be opened (a port in use).
        """
        self._open()
        self._transport.start(self._step)
        return self

    def stop(self) -> None:
        """Stop the thread and close the connection (idempotent)."""
        self._transport.stop()
        self._close()

    def serve(self, stop: threading.Event, ready: Callable[[], None] | None = None) -> None:
        """Run in the calling thread until ``stop`` is set (what ``manage.py mavsim`` does);
        ``ready`` is called once the link (and the image server) are open.

        Raises LinkError when the connection cannot be opened.
        """
        self._open()
        if ready is not None:
            ready()
        try:
            self._transport.serve(stop, self._step)
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
            return self._flight.now()

    @property
    def armed(self) -> bool:
        return self._commander.armed

    @property
    def mode(self) -> str:
        """The flight mode's name ("GUIDED", "RTL", ... or PX4's "OFFBOARD", "AUTO.RTL")."""
        return self._commander.mode

    @property
    def on_ground(self) -> bool:
        """Landed (a copter), or parked (a rover, boat or sub: not under way)."""
        return self._flight.on_ground

    def position(self) -> Position:
        """Where the vehicle is now (altitude above ground, like the platform's positions)."""
        with self._lock:
            return self._flight.here()

    def battery_fraction(self) -> float:
        """The battery's charge now, 0..1."""
        with self._lock:
            return self._flight.battery(self._flight.now())

    def flight_s(self) -> float:
        """Simulated seconds flown since the simulator started."""
        with self._lock:
            return self._flight.used_s(self._flight.now())

    def param(self, name: str) -> float:
        """A parameter's value. Raises KeyError for an unknown name."""
        with self._lock:
            return self._params.value(name)

    def message_interval_s(self, message_id: int) -> float | None:
        """The interval a message is sent at (wall seconds), or None when it is not streamed."""
        with self._lock:
            return self._telemetry.streams.intervals.get(message_id)

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
            return self._commander.auto.current

    def fence_status(self) -> FenceStatus:
        """What FENCE_STATUS reports now (a copy)."""
        with self._lock:
            return replace(self._failsafes.fence_status)

    def camera_captures(self) -> list[camera_protocol.Capture]:
        """The images taken so far, in order (index, where, when)."""
        return self._payload.camera.captures

    @property
    def camera_port(self) -> int | None:
        """The image server's port while the link is open."""
        return self._payload.camera.port

    def texts_sent(self) -> list[str]:
        """Every STATUSTEXT sent, oldest first."""
        with self._lock:
            return list(self._texts_sent)

    @property
    def gcs_heartbeats(self) -> int:
        """How many heartbeats it has received from ground stations or companions."""
        return self._telemetry.gcs_heartbeats

    # --- test hooks ---------------------------------------------------------------------

    def cut_link(self) -> None:
        """Go silent and deaf, as if the radio died: nothing is sent, everything is dropped.

        The vehicle keeps flying what it was told.
        """
        with self._lock:
            self._transport.cut = True

    def restore_link(self) -> None:
        with self._lock:
            self._transport.cut = False

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
            self._transport.drop(msg_type, count)

    def set_battery(self, fraction: float) -> None:
        """Set the battery's charge now (0..1), as a swap would."""
        with self._lock:
            self._flight.reset_battery(fraction)

    def fail_prearm(self, reason: str | None) -> None:
        """Make arming fail with this reason (a STATUSTEXT "PreArm: <reason>"), or stop."""
        with self._lock:
            self._commander.prearm_failure = reason

    # --- the loop -------------------------------------------------------------------------

    def _open(self) -> None:
        self._transport.open()
        try:
            if self.payload:
                self._payload.open()
        except OSError as exc:
            self._close()
            raise LinkError(f"mavsim cannot serve images: {exc}") from exc
        logger.info(
            "mavsim %s: %s %s on %s (speed %g)",
            self.name,
            self.flavour.autopilot.value,
            self.flavour.frame,
            self.endpoint,
            self.speed,
        )

    def _close(self) -> None:
        self._payload.close()
        self._transport.close()

    def _wall(self) -> float:
        return self.clock() - self._t0

    def _return_alt(self) -> float:
        """The altitude above home an aircraft returns at (RTL_ALT); 0 for the others."""
        if self.flavour.rtl_alt_param is None:
            return 0.0
        name, unit = self.flavour.rtl_alt_param
        return self._params.value(name) * unit

    def _step(self, msg: Any | None) -> None:
        """A message received (or None), then the clock ticks."""
        with self._lock:
            if msg is not None:
                self._receive(msg)
            self._tick()

    def _tick(self) -> None:
        self._commander.tick()
        self._failsafes.check()
        self._missions.tick()
        self._telemetry.tick()
        if self.payload:
            # After the autopilot's messages: a new ground station hears the autopilot first.
            self._payload.tick()

    def _receive(self, msg: Any) -> None:
        if not self._transport.accepts(msg):
            return
        if msg.get_type() in ("COMMAND_LONG", "COMMAND_INT"):
            server = self._payload.command_server(msg) if self.payload else None
            (server or self._commands).handle(msg, reply_to(msg))
            return
        for handle in (
            self._commander.handle,
            self._telemetry.handle,
            self._params.handle,
            self._missions.handle,
        ):
            if handle(msg):
                return

    def _execute(self, command: int, p: tuple[float, ...], frame: int) -> Outcome:
        """The autopilot's commands: those asking for messages, then the others."""
        requested = self._telemetry.command(command, p)
        if requested is not None:
            return requested
        return self._commander.execute(command, p, frame)

    def _text(self, severity: int, text: str) -> None:
        """Say something in a STATUSTEXT (unless a ground station silenced them) and the log."""
        self._texts_sent.append(text)
        logger.info("mavsim %s: %s", self.name, text)
        if self._telemetry.streams.statustext_on:
            self._transport.send(lambda mav: mav.statustext_send(severity, encode_text(text, 50)))
