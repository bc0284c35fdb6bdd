"""The MAVLink driver's state, constants and link (``fleet.mavlink.driver`` says how it flies)."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

from fleet.geo import Position
from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER, limits_of
from fleet.mavlink.link import MavlinkLink
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.tlog import TlogRecorder
from fleet.mavlink.wire import mavlink
from fleet.simulation.vehicle import VehicleSpec

logger = logging.getLogger("cpcc.mavlink.driver")

_POSITION_ONLY = (
    mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)
_ODOMETER_STEP_M = 0.5  # GPS jitter below this does not count as distance flown
_LANDING_RADIUS_M = 2.0  # a returning vehicle this close to home is landing
_ARDUPILOT_RESEND_S = 1.0
_PX4_STREAM_HZ = 4.0
_PX4_OFFBOARD_AFTER_S = 1.2  # PX4 enters offboard after a second of setpoints
_STUCK_ARMED_S = 5.0  # landed but still armed this long after returning: disarm
_STANDING_MPS = 0.3  # a rover, boat or sub this slow has stopped
_SURFACE_M = 0.3  # a sub this close below home's altitude is at the surface
_CAMERA = mavlink.MAV_COMP_ID_CAMERA  # the camera component (MAVLink camera protocol)
_MAX_PICTURE_BYTES = 20_000_000

# Flying states and the modes the autopilot may show in them without the driver being
# overruled (PX4 switches from AUTO.TAKEOFF to AUTO.LOITER by itself, RTL ends in LAND).
_MODES = {
    Autopilot.ARDUPILOT: {
        "takeoff": frozenset({"GUIDED"}),
        "goto": frozenset({"GUIDED"}),
        "return": frozenset({"RTL", "LAND"}),
        "land": frozenset({"LAND"}),
    },
    Autopilot.PX4: {
        "takeoff": frozenset({"AUTO.TAKEOFF", "AUTO.LOITER"}),
        "goto": frozenset({"OFFBOARD", "AUTO.LOITER", "AUTO.TAKEOFF"}),
        "return": frozenset({"AUTO.RTL", "AUTO.LAND"}),
        "land": frozenset({"AUTO.LAND"}),
    },
}
# The same for the vehicles that do not fly (Autopilot.ARDUPILOT only), by kind.
_GROUND_MODES = {
    "goto": frozenset({"GUIDED"}),
    "return": frozenset({"RTL"}),
    "land": frozenset({"HOLD"}),
}
_KIND_MODES = {
    GROUND: _GROUND_MODES,
    SURFACE: _GROUND_MODES,
    UNDERWATER: {
        "goto": frozenset({"GUIDED"}),
        "return": frozenset({"GUIDED"}),
        "land": frozenset({"SURFACE"}),
    },
}
_RETURN_MODES = frozenset(
    {"RTL", "LAND", "AUTO.RTL", "AUTO.LAND", "SMART_RTL", "AUTO_RTL", "SURFACE"}
)


class Fence(NamedTuple):
    """What a vehicle's autopilot was given by ``upload_fence``: the area's vertices (the
    inclusion polygon), the altitude range, each no-fly zone's vertices and the rally points
    as (lat, lng, altitude above home)."""

    area: list[tuple[float, float]]
    min_altitude_m: float
    max_altitude_m: float
    exclusions: tuple[tuple[tuple[float, float], ...], ...] = ()
    rally: tuple[tuple[float, float, float], ...] = ()


class DriverState:
    """What every part of the MAVLink driver reads and writes, and the link under it: the
    telemetry, the state of the flight, the locks (``MavlinkDriver`` says what the parameters
    are). The parts build on each other in one line, each using only those below it:
    ``DriverState``, ``Telemetry`` (the reader thread's handlers and the driver API's queries),
    ``Sensors`` (readings and the camera), ``Guidance`` (the modes and the setpoint loop),
    ``Flight`` (the driver API's commands), ``MavlinkDriver`` (connecting, set-up, the fence)."""

    def __init__(
        self,
        connection: str | MavlinkLink,
        *,
        spec: VehicleSpec,
        depot: Position,
        area: Sequence[Sequence[float]] | None = None,
        min_altitude_m: float = 0.0,
        max_altitude_m: float | None = None,
        exclusions: Sequence[Sequence[Sequence[float]]] = (),
        rally: Sequence[Position] = (),
        clock: Callable[[], float] = time.time,
        telemetry_hz: float = 4.0,
        link_timeout_s: float = 3.0,
        command_timeout_s: float = 1.0,
        command_attempts: int = 3,
        arrival_tolerance_m: float = 1.0,
        on_link_lost: Callable[[], None] | None = None,
        name: str = "",
        gcs_failsafe_s: float | None = None,
        kind: str | None = None,
    ) -> None:
        if isinstance(connection, MavlinkLink):
            self.link = connection
        else:
            self.link = MavlinkLink(
                connection,
                link_timeout_s=link_timeout_s,
                command_timeout_s=command_timeout_s,
                command_attempts=command_attempts,
            )
        self.link.on_link_lost = self._on_link_lost
        self.link.on_link_regained = self._on_link_regained
        self.spec = spec
        self.depot = depot
        self.clock = clock
        self.telemetry_hz = telemetry_hz
        self.arrival_tolerance_m = arrival_tolerance_m
        self.on_link_lost = on_link_lost
        self.gcs_failsafe_s = gcs_failsafe_s
        if kind is not None:
            limits_of(kind)  # ValueError for a kind there is not
        self.configured_kind = kind
        # What the vehicle is (its heartbeat's type, once connected).
        self.kind = kind if kind is not None else AERIAL
        self.measures_battery = True  # SYS_STATUS, BATTERY_STATUS
        self.reports_arrival = True  # GLOBAL_POSITION_INT
        self.name = name or str(self.link.endpoint)
        # The flight's .tlog: the worker starts it at the take-off and finishes it at the
        # landing; the link feeds it every message both ways.
        self.flight_log = TlogRecorder(name=self.name)
        self.link.recorder = self.flight_log
        self._fence_request = (
            (area, min_altitude_m, max_altitude_m, exclusions, rally)
            if area is not None and max_altitude_m is not None
            else None
        )
        self.fence: Fence | None = None  # what the autopilot was given last
        # Set while what the old connection said is stale (the link came back, the autopilot
        # restarted): no command is sent and the link does not count as up until it is read
        # again (``_resync``).
        self._resync_due = threading.Event()
        self._boot_ms: int | None = None  # the autopilot's uptime as last reported

        self._lock = threading.RLock()
        self._command_lock = threading.Lock()  # one flight command sequence at a time
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._guidance: threading.Thread | None = None
        self._removers: list[Callable[[], None]] = []

        # Telemetry.
        self._position = depot
        self._ground_speed_mps = 0.0  # GLOBAL_POSITION_INT's vx, vy
        self._climb_mps = 0.0  # GLOBAL_POSITION_INT's vz, up
        self._heading_deg: float | None = None  # GLOBAL_POSITION_INT's hdg
        self._position_seen_s: float | None = None
        self._home_amsl_m: float | None = None
        self._battery: float | None = None
        self._captures = 0  # pictures asked for (MAV_CMD_IMAGE_START_CAPTURE sequence numbers)
        self._landed_state: int | None = None
        self._armed = False
        self._mode = ""
        # Odometry and flight time (platform clock).
        self._distance_m = 0.0
        self._odometer_anchor: Position | None = None
        self._flight_before_s = 0.0
        self._armed_since_s: float | None = None
        # What the driver is doing.
        self._state = "idle"  # "idle", "takeoff", "goto", "return", "land"
        self._target: Position | None = None  # where the vehicle is going now
        self._pending: Position | None = None  # where to go once the take-off is done
        self._goal_modes: frozenset[str] = frozenset()
        self._allowed_modes: frozenset[str] = frozenset()
        self._took_over: str | None = None
        self._last_setpoint = -math.inf  # monotonic
        self._stream_since: float | None = None  # PX4: when the setpoint stream started
        self._on_ground_since: float | None = None  # monotonic, while returning

    @property
    def flies(self) -> bool:
        """An aircraft: it takes off and lands (a rover, boat or sub is parked or under way)."""
        return self.kind == AERIAL

    @property
    def link_ok(self) -> bool:
        """Whether the vehicle's heartbeat is fresh and what the driver knows of it is
        current (not during the resynchronisation after the link returned)."""
        return self.link.link_ok and not self._resync_due.is_set()

    @property
    def uptime_s(self) -> float | None:
        """How long the autopilot has been up, as its last position report said."""
        return None if self._boot_ms is None else self._boot_ms / 1000

    @property
    def autopilot(self) -> Autopilot:
        return self.link.autopilot

    @property
    def took_over(self) -> str | None:
        """The mode a pilot or failsafe switched the flying vehicle to, or None while the
        driver is in control (cleared when the vehicle disarms)."""
        return self._took_over

    def _flavour(self) -> Autopilot:
        autopilot = self.autopilot
        return autopilot if autopilot in _MODES else Autopilot.ARDUPILOT

    def _modes(self, state: str) -> frozenset[str]:
        """The modes the vehicle may show in a state without being overruled."""
        if not self.flies:
            return _KIND_MODES[self.kind][state]
        return _MODES[self._flavour()][state]

    def _reachable(self, target: Position) -> Position:
        """Where a rover or boat goes for ``target``: at home's altitude (ArduRover ignores
        altitudes); a sub: no higher than the surface."""
        if self.kind in (GROUND, SURFACE) or target.alt > self.depot.alt:
            return target.with_alt(self.depot.alt)
        return target

    def _on_link_lost(self) -> None:
        logger.warning("%s: link lost", self.name)
        if self.on_link_lost is not None:
            self.on_link_lost()

    def _on_link_regained(self) -> None:
        logger.warning("%s: link regained: resynchronising", self.name)
        self._resync_due.set()
        self._wake.set()
