"""MavlinkDriver: one real vehicle flown over MAVLink, behind the RV control loop's driver API.

It answers the same questions as the in-process simulator's ``SimVehicle`` (``fly_to``,
``return_to_depot``, ``position_at``, ``phase_at``, ``is_landed_at``, ``distance_m``,
``flight_s``, ``battery_remaining_s``, ``time_to_s``, ``time_home_s``, ``recharge``), but a
real vehicle is not a plan: ``fly_to`` and ``return_to_depot`` *command* the autopilot and
return an *estimated* arrival or landing time (the vehicle's configured speed and climb rate
over ``fleet.geo`` distances, the simulator's kinematics), and the queries answer from the
latest telemetry whatever ``t`` they are given. Arrival is ``has_arrived``: the last
GLOBAL_POSITION_INT within a 3-D tolerance of the target.

How it flies:

- ArduPilot (ArduCopter): mode GUIDED, arm, MAV_CMD_NAV_TAKEOFF to a safe altitude (the target's
  altitude, at least the spec's take-off altitude, relative to home), and once up
  SET_POSITION_TARGET_GLOBAL_INT (frame GLOBAL_RELATIVE_ALT_INT, position only), re-sent every
  second because the message has no acknowledgement; home with MAV_CMD_NAV_RETURN_TO_LAUNCH
  (RTL mode if the command is unsupported), which lands and disarms.
- PX4: arm, MAV_CMD_NAV_TAKEOFF (its altitude is AMSL on PX4), then offboard position control:
  SET_POSITION_TARGET_GLOBAL_INT streamed at 4 Hz (PX4 leaves offboard below 2 Hz, and only
  enters it once the stream has run for a second), frame GLOBAL_INT with AMSL altitude
  (what every PX4 release accepts in offboard), and the switch to OFFBOARD; home with
  MAV_CMD_NAV_RETURN_TO_LAUNCH.
- An operator's "land now" (``land``): MAV_CMD_NAV_LAND where the vehicle is (LAND mode if
  the command is unsupported); the autopilot lands and disarms there.
- A rover or a boat (ArduRover, HEARTBEAT type GROUND_ROVER or SURFACE_BOAT): GUIDED, arm and
  SET_POSITION_TARGET_GLOBAL_INT at altitude 0 (no take-off: it drives off), re-sent as for
  a copter; home with MAV_CMD_NAV_RETURN_TO_LAUNCH (RTL mode if unsupported), which drives
  home and stops there armed, so the driver disarms it once it stands at home; "land now" is
  HOLD where it is, then a disarm once it stands. Landed means disarmed: parked.
- A submarine (ArduSub, SUBMARINE): GUIDED, arm and position targets whose relative altitude
  is the depth (below 0); ArduSub has no RTL: home is GUIDED to home at the surface, then a
  disarm once there; "land now" is SURFACE (it rises where it is), then a disarm once it is up.

The vehicle's kind comes from its HEARTBEAT type (``fleet.mavlink.modes.KIND_OF_TYPE``); a
``kind`` the platform configured for it that differs is refused on connecting.

If the vehicle leaves the mode the driver put it in while flying (a pilot, or a failsafe:
battery, fence, radio), the driver stops commanding it: ``fly_to`` raises VehicleTookOver and
``return_to_depot`` only accepts a vehicle already returning or landing.

Times ``now_s``/``t`` are platform-clock seconds; ``clock`` (injectable) is that clock, used
to time-stamp telemetry (flight time). Link timeouts run on the monotonic clock.
"""

from __future__ import annotations

import io
import logging
import math
import threading
import time
import urllib.parse
import urllib.request
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import PIL.Image

from fleet.driving import Sample, SensorFailure, SensorRead
from fleet.geo import Position, distance_m, ground_distance_m, headings_deg, turn_deg
from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER, a_vehicle, limits_of
from fleet.kinematics import from_ground_s, leg_s
from fleet.mavlink.errors import (
    CommandDenied,
    LinkLost,
    MavlinkError,
    UnsupportedVehicle,
    VehicleTookOver,
)
from fleet.mavlink.link import MavlinkLink
from fleet.mavlink.mission import exclusion_polygons, fence_polygon_items, rally_items
from fleet.mavlink.modes import KIND_OF_TYPE, KIND_WORDS, Autopilot
from fleet.mavlink.wire import mavlink
from fleet.simulation.vehicle import (
    PHASE_CRUISE,
    PHASE_HOVERING,
    PHASE_LANDED,
    PHASE_LANDING,
    PHASE_TAKEOFF,
    VehicleSpec,
)

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


class MavlinkDriver:
    """Flies one ArduPilot or PX4 copter, or an ArduRover rover or boat, or an ArduSub
    submarine, over a MAVLink link (see the module docstring).

    ``connection``: a connection string (``fleet.mavlink.endpoint``) or an unopened
    ``MavlinkLink``. ``spec``: the vehicle's speed, climb rate, take-off altitude and battery
    endurance (for estimates and ``battery_remaining_s``). ``depot``: its home, where it arms
    (the autopilot's home is where it armed, so altitudes relative to home are relative to the
    depot). ``area``/``min_altitude_m``/``max_altitude_m``: the geofence to upload on connect
    (None: none), with ``exclusions`` (no-fly zones' rings) and ``rally`` points (see
    ``upload_fence``). ``clock``: the platform clock. ``telemetry_hz``: the GLOBAL_POSITION_INT rate
    to ask for. ``arrival_tolerance_m``: how close counts as "there" for ``phase_at``.
    ``on_link_lost``: called (on the link's thread) when the heartbeat stops.
    ``gcs_failsafe_s``: the autopilot's GCS failsafe is turned on (return home when it hears
    no ground station for this long: the worker stopped, the link died) on every connection;
    an autopilot that cannot is not flown. None: left as the autopilot has it. ``kind``: the
    kind the platform configured the vehicle as (``fleet.kinds``); connecting to a vehicle
    whose heartbeat says otherwise is refused. None: whatever the heartbeat says.
    """

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

    # --- life cycle -----------------------------------------------------------------------

    def connect(self, timeout_s: float = 10.0) -> None:
        """Open the link, wait for the vehicle, set up telemetry and upload the fence.

        Asks for GLOBAL_POSITION_INT at ``telemetry_hz`` and SYS_STATUS, BATTERY_STATUS,
        EXTENDED_SYS_STATE, HEARTBEAT and STATUSTEXT (MAV_CMD_SET_MESSAGE_INTERVAL; only the
        position is required, the others are best effort), reads HOME_POSITION, uploads the
        geofence given to the constructor, and starts the guidance thread. Raises LinkError
        (cannot open), LinkLost (no heartbeat in ``timeout_s``), UnsupportedVehicle (not an
        ArduPilot or PX4 copter, nor an ArduPilot rover, boat or submarine, or not the kind
        configured), and what the requests raise; the link is closed on failure.
        """
        try:
            self.link.open()
            beat = self.link.wait_heartbeat(timeout_s)
            if beat.autopilot is Autopilot.OTHER:
                raise UnsupportedVehicle(
                    f"{self.name}: autopilot {beat.autopilot.value} is neither ArduPilot nor PX4"
                )
            self.kind = self._kind_of(beat.mav_type, beat.autopilot)
            self._removers = [
                self.link.add_listener("HEARTBEAT", self._on_heartbeat),
                self.link.add_listener("GLOBAL_POSITION_INT", self._on_position),
                self.link.add_listener("SYS_STATUS", self._on_sys_status),
                self.link.add_listener("BATTERY_STATUS", self._on_battery_status),
                self.link.add_listener("EXTENDED_SYS_STATE", self._on_extended_state),
                self.link.add_listener("HOME_POSITION", self._on_home),
            ]
            self._on_heartbeat_state(beat.armed, beat.mode)
            self._set_up()
        except BaseException:
            self.close()
            raise
        self._stop.clear()
        self._guidance = threading.Thread(
            target=self._guidance_loop, name=f"mavlink-guidance {self.name}", daemon=True
        )
        self._guidance.start()

    def _kind_of(self, mav_type: int, autopilot: Autopilot) -> str:
        """The kind of vehicle a heartbeat's type is, checked against the configured kind.
        Raises UnsupportedVehicle."""
        kind = KIND_OF_TYPE.get(mav_type)
        if kind is None:
            raise UnsupportedVehicle(
                f"{self.name}: MAV_TYPE {mav_type} is not a copter, rover, boat or submarine"
            )
        if kind != AERIAL and autopilot is not Autopilot.ARDUPILOT:
            raise UnsupportedVehicle(
                f"{self.name}: {KIND_WORDS[kind]} is flown on ArduPilot only, not on "
                f"{autopilot.value}"
            )
        configured = self.configured_kind
        if configured is not None and kind != configured:
            raise UnsupportedVehicle(
                f"{self.name}: configured as {a_vehicle(configured)}, but the autopilot reports "
                f"{KIND_WORDS[kind]}"
            )
        return kind

    @property
    def flies(self) -> bool:
        """An aircraft: it takes off and lands (a rover, boat or sub is parked or under way)."""
        return self.kind == AERIAL

    def _set_up(self) -> None:
        """What the vehicle is asked for on every connection (the first, and each time the
        link returns or the autopilot restarts): the telemetry rates, its home, the fence."""
        self.link.set_message_interval(
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, self.telemetry_hz
        )
        for message_id, rate_hz in (
            (mavlink.MAVLINK_MSG_ID_SYS_STATUS, 1.0),
            (mavlink.MAVLINK_MSG_ID_BATTERY_STATUS, 1.0),
            (mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 1.0),
            (mavlink.MAVLINK_MSG_ID_HEARTBEAT, 1.0),
            (mavlink.MAVLINK_MSG_ID_STATUSTEXT, 1.0),
            # What its sensors' readings come from (fleet.sources: telemetry).
            (mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, 1.0),
            (mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE, 2.0),
        ):
            try:
                self.link.set_message_interval(message_id, rate_hz)
            except MavlinkError as exc:
                logger.info("%s: message %d rate not set: %s", self.name, message_id, exc)
        try:
            self.link.request_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION)
        except MavlinkError as exc:
            logger.warning("%s: no HOME_POSITION: %s", self.name, exc)
        if self._fence_request is not None:
            area, low, high, exclusions, rally = self._fence_request
            self.upload_fence(area, low, high, exclusions=exclusions, rally=rally)
        self._arm_gcs_failsafe()

    def _arm_gcs_failsafe(self) -> None:
        """Turn the autopilot's GCS failsafe on (home when no ground station is heard for
        ``gcs_failsafe_s``): ArduCopter's FS_GCS_ENABLE (1, RTL, unless another action is
        set) and FS_GCS_TIMEOUT, PX4's NAV_DLL_ACT (2, Return, unless set) and COM_DL_LOSS_T.
        What the autopilot refuses raises (no flight without it)."""
        if self.gcs_failsafe_s is None:
            return
        if self.autopilot is Autopilot.PX4:
            enable, action, timeout = "NAV_DLL_ACT", 2, "COM_DL_LOSS_T"
        elif self.kind in (GROUND, SURFACE):
            # ArduRover: FS_GCS_ENABLE 1 takes FS_ACTION (HOLD as it ships, or RTL) after
            # FS_TIMEOUT; an action of "nothing" becomes RTL.
            enable, action, timeout = "FS_GCS_ENABLE", 1, "FS_TIMEOUT"
            if self.link.param_get("FS_ACTION") == 0:
                self.link.param_set("FS_ACTION", 1)
        elif self.kind == UNDERWATER:
            # ArduSub: FS_GCS_ENABLE is the action; "warn only" protects nothing: surface.
            enable, action, timeout = "FS_GCS_ENABLE", 4, "FS_GCS_TIMEOUT"
            if self.link.param_get(enable) == 1:
                self.link.param_set(enable, action)
        else:
            enable, action, timeout = "FS_GCS_ENABLE", 1, "FS_GCS_TIMEOUT"
        if self.link.param_get(enable) == 0:
            self.link.param_set(enable, action)
        self.link.param_set(timeout, self.gcs_failsafe_s)
        logger.info(
            "%s: GCS failsafe on: home after %g s without the platform",
            self.name,
            self.gcs_failsafe_s,
        )

    def _resync(self) -> None:
        """The link is back (or the autopilot restarted): forget what the old connection
        said of the vehicle's state, read it fresh and set the vehicle up again."""
        with self._lock:
            self._landed_state = None
            self._on_ground_since = None
        beat = self.link.heartbeat
        if beat is not None:
            self._on_heartbeat_state(beat.armed, beat.mode)
        self._set_up()
        logger.warning("%s: link resynchronised (telemetry, home, fence)", self.name)
        self._resync_due.clear()

    def close(self) -> None:
        """Stop the guidance thread and close the link (idempotent). The vehicle keeps doing
        what it was last told; an autopilot's GCS failsafe decides what happens next."""
        self._stop.set()
        self._wake.set()
        if self._guidance is not None and self._guidance is not threading.current_thread():
            self._guidance.join(timeout=5.0)
        self._guidance = None
        for remove in self._removers:
            remove()
        self._removers = []
        self.link.close()

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

    # --- geofence -------------------------------------------------------------------------

    def upload_fence(
        self,
        area: Sequence[Sequence[float]],
        min_altitude_m: float,
        max_altitude_m: float,
        *,
        exclusions: Sequence[Sequence[Sequence[float]]] = (),
        rally: Sequence[Position] = (),
    ) -> None:
        """Upload the operation area as the vehicle's geofence, with its altitude ceiling, the
        provider's no-fly zones as exclusion polygons and its rally points.

        The area (a ring of (lat, lng), closed or not) becomes one inclusion polygon and each
        ring of ``exclusions`` an exclusion polygon (MAV_MISSION_TYPE_FENCE); the ceiling is
        set relative to home (``FENCE_ALT_MAX`` and FENCE_TYPE's altitude and polygon bits, its
        circle bit cleared, then ``FENCE_ENABLE`` on ArduPilot; ``GF_MAX_VER_DIST`` on PX4,
        whose fence acts when GF_ACTION is not "none": it is set to Return if it was). The
        ``rally`` points (altitudes above ground) become the rally list
        (MAV_MISSION_TYPE_RALLY; an empty one clears it). The minimum altitude is not put on
        the autopilot (a floor would trip on every take-off and landing): the platform keeps
        tasks above it. A rover, boat or sub gets the polygons only (FENCE_TYPE's polygon bit,
        no ceiling: a rover or boat stays at 0, a sub's ceiling is the surface), and a rover's
        or boat's range may be the one altitude 0. Call again whenever any of it changes.
        Raises ValueError for a bad area or altitude range, MissionRejected/MissionTimeout, and
        the parameter errors.
        """
        planar = not limits_of(self.kind).vertical
        if not (max_altitude_m > min_altitude_m or (planar and max_altitude_m == min_altitude_m)):
            raise ValueError(
                f"max altitude {max_altitude_m!r} must be above min altitude {min_altitude_m!r}"
            )
        self._fence_request = (area, min_altitude_m, max_altitude_m, exclusions, rally)
        items = fence_polygon_items(area)
        for ring in exclusions:
            items += fence_polygon_items(ring, exclusion=True, first_seq=len(items))
        ceiling = max_altitude_m - self.depot.alt
        self.link.upload_mission(items, mavlink.MAV_MISSION_TYPE_FENCE)
        points = [(p.lat, p.lng, p.alt - self.depot.alt) for p in rally]
        self.link.upload_mission(rally_items(points), mavlink.MAV_MISSION_TYPE_RALLY)
        if self.autopilot is Autopilot.PX4:
            self.link.param_set("GF_MAX_VER_DIST", ceiling)
            if self.link.param_get("GF_ACTION") == 0:
                self.link.param_set("GF_ACTION", 3)  # Return
        elif not self.flies:
            # The polygons only: no altitude fence, nor the circle around home.
            fence_type = int(self.link.param_get("FENCE_TYPE"))
            self.link.param_set("FENCE_TYPE", (fence_type | 4) & ~(1 | 2))
            self.link.param_set("FENCE_ENABLE", 1)
        else:
            self.link.param_set("FENCE_ALT_MAX", ceiling)
            # Max altitude and polygon; not ArduCopter's default circle around home
            # (FENCE_RADIUS, 300 m), which would refuse targets in a larger area.
            fence_type = int(self.link.param_get("FENCE_TYPE"))
            self.link.param_set("FENCE_TYPE", (fence_type | 1 | 4) & ~2)
            self.link.param_set("FENCE_ENABLE", 1)
        inclusion = [(i.lat, i.lng) for i in items[: int(items[0].param1)]]
        self.fence = Fence(
            inclusion,
            min_altitude_m,
            max_altitude_m,
            tuple(tuple(p) for p in exclusion_polygons(items)),
            tuple(points),
        )
        logger.info(
            "%s: geofence of %d vertices and %d no-fly zone(s), ceiling %.1f m, %d rally "
            "point(s) uploaded",
            self.name,
            len(inclusion),
            len(exclusions),
            ceiling,
            len(points),
        )

    # --- commands (the driver API) ----------------------------------------------------------

    def fly_to(self, target: Position, now_s: float) -> float:
        """Send the vehicle to ``target`` (altitude above ground); returns the estimated arrival.

        From the ground: mode, arm, take off to ``max(target.alt, spec.takeoff_alt_m)``, and the
        target once that altitude is reached (the guidance thread does it). In the air: the
        new target at once. The estimate is ``now_s`` plus the simulator's flight time from
        the last known position. Raises LinkLost, VehicleTookOver (permanent), PreArmFailed
        with the vehicle's reasons, CommandDenied/CommandTimeout (after a failed take-off
        command the vehicle is disarmed again, best effort), ModeChangeFailed.
        """
        with self._command_lock:
            self._check_usable(returning_ok=False)
            eta = now_s + self.time_to_s(target, now_s)
            if not self.flies:
                self._drive_off_towards(target)
            elif self.is_landed_at(now_s):
                self._take_off_towards(target)
            else:
                self._go(target)
            return eta

    def return_to_depot(self, now_s: float) -> float:
        """Send the vehicle home to land (RTL); returns the estimated landing time.

        ``now_s`` when it is already landed. The autopilot lands and disarms by itself; the
        guidance thread disarms a vehicle that stays armed on the ground (a rover or boat
        home, a sub: GUIDED home at the surface, disarmed there). Raises LinkLost,
        VehicleTookOver (unless the vehicle is already returning or landing by itself),
        CommandDenied/CommandTimeout, ModeChangeFailed.
        """
        with self._command_lock:
            if self.is_landed_at(now_s):
                return now_s
            self._check_usable(returning_ok=True)
            eta = now_s + self.time_home_s(self._position)
            if self._took_over is not None:
                return eta  # already returning or landing by itself
            if self.kind == UNDERWATER:
                self._go(self.depot, state="return")
                logger.info("%s: surfacing at home", self.name)
                return eta
            modes = self._modes("return")
            with self._lock:
                before = (self._state, self._target, self._pending, self._stream_since)
                self._state = "return"
                self._target = self.depot
                self._pending = None
                self._stream_since = None
                self._set_goal(modes)
            try:
                try:
                    self.link.command_long(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)
                except CommandDenied as exc:
                    if exc.result != mavlink.MAV_RESULT_UNSUPPORTED:
                        raise
                    self.link.set_mode("AUTO.RTL" if self.autopilot is Autopilot.PX4 else "RTL")
            except MavlinkError:
                with self._lock:  # still doing what it did: say so
                    self._state, self._target, self._pending, self._stream_since = before
                raise
            logger.info("%s: returning to launch", self.name)
            return eta

    def land(self, now_s: float) -> float:
        """Land where the vehicle is (an operator's "land now"); returns the estimated
        touchdown time: the descent at the climb rate.

        MAV_CMD_NAV_LAND at the current position (LAND or AUTO.LAND mode when the command is
        unsupported); the autopilot lands and disarms there, and the guidance thread disarms
        a vehicle that stays armed on the ground. ``now_s`` when it is already landed. Sent
        also to a vehicle returning or landing by itself (a failsafe's RTL becomes a landing
        here). A rover or boat: HOLD where it is (then disarmed once it stands); a sub:
        SURFACE, rising where it is (then disarmed at the surface). Raises LinkLost,
        VehicleTookOver (a pilot flies it), CommandDenied/CommandTimeout, ModeChangeFailed.
        """
        with self._command_lock:
            if self.is_landed_at(now_s):
                return now_s
            self._check_usable(returning_ok=True)
            if not self.flies:
                return self._stop_here(now_s)
            eta = now_s + max(0.0, self._position.alt - self.depot.alt) / self.spec.climb_rate_mps
            px4 = self.autopilot is Autopilot.PX4
            with self._lock:
                before = (self._state, self._target, self._pending, self._stream_since)
                self._state = "land"
                self._target = self._position.with_alt(self.depot.alt)
                self._pending = None
                self._stream_since = None
                self._set_goal(self._modes("land"))
            # Where it is: NaN (PX4) or 0 (ArduPilot) for latitude and longitude.
            nan = math.nan
            params = (0.0, 0.0, 0.0, nan, nan, nan, 0.0) if px4 else (0.0,) * 7
            try:
                try:
                    self.link.command_long(mavlink.MAV_CMD_NAV_LAND, params)
                except CommandDenied as exc:
                    if exc.result != mavlink.MAV_RESULT_UNSUPPORTED:
                        raise
                    self.link.set_mode("AUTO.LAND" if px4 else "LAND")
            except MavlinkError:
                with self._lock:  # still doing what it did: say so
                    self._state, self._target, self._pending, self._stream_since = before
                raise
            logger.info("%s: landing where it is", self.name)
            return eta

    def recharge(self, now_s: float, duration_s: float) -> float:
        """When a charge (or a battery swap) of ``duration_s`` started now will be done.

        A real battery is charged or swapped by people, not over the link: this only keeps
        the control loop's timing; ``battery_remaining_s`` keeps reporting what the vehicle
        measures. Raises ValueError when the vehicle is not landed or the duration is bad.
        """
        if not self.is_landed_at(now_s):
            raise ValueError(f"{self.name} is not landed: it cannot charge")
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"duration_s must be a finite number >= 0, got {duration_s!r}")
        return now_s + duration_s

    # --- sensors ------------------------------------------------------------------------------

    def read_sensor(self, read: SensorRead) -> Sample:
        """A reading of the vehicle's own sensor, the way ArduPilot and PX4 publish it: the
        next message that carries it, received from now on within ``read.timeout_s`` (never
        one from before the vehicle got here). GPS and altitude: GLOBAL_POSITION_INT (with
        GPS_RAW_INT's satellites and HDOP); pressure and temperature: SCALED_PRESSURE;
        battery: SYS_STATUS; a named value: NAMED_VALUE_FLOAT of that name from any
        component of the vehicle. Raises SensorFailure when it does not come."""
        quantity = str(read.params.get("quantity", "")).lower()
        if read.source == "named_value":
            what = f"NAMED_VALUE_FLOAT {read.name!r}"
            msg = self._next(
                lambda m: m.get_type() == "NAMED_VALUE_FLOAT" and _text(m.name) == read.name,
                read,
                what,
                any_component=True,
            )
            return self._sample({"value": round(float(msg.value), 4)})
        if read.source == "camera":
            return self._capture(read)
        if read.source != "telemetry":
            raise SensorFailure(f"this vehicle has no {read.source} source", where=read.sensor)
        if read.kind == "gps" or quantity == "altitude":
            msg = self._next(_is("GLOBAL_POSITION_INT"), read, "GLOBAL_POSITION_INT")
            if msg.lat == 0 and msg.lon == 0:
                raise SensorFailure("the autopilot has no position fix", where=read.sensor)
            alt = self.depot.alt + msg.relative_alt / 1000
            if read.kind != "gps":
                return self._sample({"value": round(alt, 2)})
            fields: dict[str, Any] = {"lat": msg.lat / 1e7, "lng": msg.lon / 1e7, "alt": alt}
            raw = self.link.last_message("GPS_RAW_INT")
            if raw is not None:
                fields["satellites"] = (
                    None if raw.satellites_visible == 255 else raw.satellites_visible
                )
                fields["hdop"] = None if raw.eph == 65535 else round(raw.eph / 100, 2)
            return self._sample(fields)
        if quantity in ("pressure", "temperature"):
            msg = self._next(_is("SCALED_PRESSURE"), read, "SCALED_PRESSURE")
            value = msg.press_abs if quantity == "pressure" else msg.temperature / 100
            return self._sample({"value": round(float(value), 2)})
        if quantity == "battery":
            msg = self._next(
                lambda m: m.get_type() == "SYS_STATUS" and m.battery_remaining >= 0,
                read,
                "SYS_STATUS with the battery's charge",
            )
            return self._sample({"value": float(msg.battery_remaining)})
        raise SensorFailure(
            f"the autopilot's telemetry has no {quantity or read.kind}", where=read.sensor
        )

    def _next(
        self,
        match: Callable[[Any], bool],
        read: SensorRead,
        what: str,
        *,
        any_component: bool = False,
    ) -> Any:
        if not self.link.link_ok:
            raise SensorFailure("the vehicle's link is down", where=f"{self.name}: {read.sensor}")
        msg = self.link.next_message(match, read.timeout_s, any_component=any_component)
        if msg is None:
            raise SensorFailure(
                f"no reading within {read.timeout_s:g} s",
                where=f"{self.name}: {read.sensor} ({what})",
            )
        return msg

    def _capture(self, read: SensorRead) -> Sample:
        """A picture through the MAVLink camera protocol: MAV_CMD_IMAGE_START_CAPTURE (one
        image) to the camera component, its CAMERA_IMAGE_CAPTURED (time and position of the
        capture, the picture's URI), then the picture fetched from that URI."""
        where = f"{self.name}: {read.sensor} (camera {_CAMERA})"
        if not self.link.link_ok:
            raise SensorFailure("the vehicle's link is down", where=where)
        deadline = time.monotonic() + read.timeout_s
        self._captures += 1
        sequence = self._captures

        def is_captured(msg: Any) -> bool:
            return bool(
                msg.get_type() == "CAMERA_IMAGE_CAPTURED" and msg.get_srcComponent() == _CAMERA
            )

        with self.link.waiting(is_captured, any_component=True) as captured:
            try:
                self.link.command_long(
                    mavlink.MAV_CMD_IMAGE_START_CAPTURE,
                    [0, 0, 1, sequence],
                    component=_CAMERA,
                    timeout_s=min(1.0, read.timeout_s),
                )
            except CommandDenied as exc:
                raise SensorFailure(
                    "the camera refused to take a picture", where=f"{where}: {exc}"
                ) from exc
            except MavlinkError as exc:
                raise SensorFailure("the camera did not answer", where=f"{where}: {exc}") from exc
            msg = captured.get(deadline - time.monotonic())
        if msg is None:
            raise SensorFailure(f"no picture within {read.timeout_s:g} s", where=where)
        if msg.capture_result != 1:
            raise SensorFailure("the camera could not take the picture", where=where)
        url = _text(msg.file_url)
        image, fmt, width, height = _fetch_picture(
            url, max(0.1, deadline - time.monotonic()), where
        )
        taken_ms = msg.time_utc // 1000 if msg.time_utc > 0 else int(time.time() * 1000)
        try:
            at = Position(msg.lat / 1e7, msg.lon / 1e7, self.depot.alt + msg.relative_alt / 1000)
        except ValueError:
            at = self._position
        fields = {"width": width, "height": height, "format": fmt}
        return Sample(fields=fields, epoch_ms=int(taken_ms), position=at, image=image)

    def _sample(self, fields: dict[str, Any]) -> Sample:
        """The reading as the vehicle took it: now (the vehicle's message just came) and where
        its telemetry says it is."""
        return Sample(fields=fields, epoch_ms=int(time.time() * 1000), position=self._position)

    # --- queries (the driver API) -----------------------------------------------------------

    def position_at(self, t: float) -> Position:
        """The last reported position (altitude above ground: relative altitude + depot's),
        whatever ``t``: a real vehicle is where it is. The depot before any telemetry."""
        return self._position

    def phase_at(self, t: float) -> str:
        """One of "landed", "takeoff", "cruise", "hovering", "landing", from the driver's
        state and the last telemetry (``t`` is not used). A rover, boat or sub is landed when
        disarmed (parked), or armed and idle standing at home; "landing" while it stops."""
        with self._lock:
            if not self._armed:
                return PHASE_LANDED
            here = self._position
            if self._took_over is not None:
                if self._took_over in _RETURN_MODES:
                    return self._return_phase(here)
                return PHASE_HOVERING
            if self._state == "takeoff":
                return PHASE_TAKEOFF
            if self._state == "goto" and self._target is not None:
                near = distance_m(here, self._target) <= self.arrival_tolerance_m
                return PHASE_HOVERING if near else PHASE_CRUISE
            if self._state == "return":
                return self._return_phase(here)
            if self._state == "land" and not self.flies:
                return PHASE_LANDING  # until it stands and is disarmed
            if self._state == "land":
                # Down once near home's height (EXTENDED_SYS_STATE may still say "on the
                # ground" from before the take-off), or once it disarms (higher ground).
                return PHASE_LANDED if here.alt - self.depot.alt < 0.5 else PHASE_LANDING
            if not self.flies:
                standing = self._ground_speed_mps <= _STANDING_MPS
                home = ground_distance_m(here, self.depot) <= _LANDING_RADIUS_M
                surfaced = here.alt >= self.depot.alt - _SURFACE_M
                return PHASE_LANDED if standing and home and surfaced else PHASE_HOVERING
            if self._landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND or (
                here.alt - self.depot.alt < 0.5
            ):
                return PHASE_LANDED
            return PHASE_HOVERING

    def _return_phase(self, here: Position) -> str:
        if self._landed_state == mavlink.MAV_LANDED_STATE_LANDING or (
            ground_distance_m(here, self.depot) <= _LANDING_RADIUS_M
        ):
            return PHASE_LANDING
        return PHASE_CRUISE

    def is_landed_at(self, t: float) -> bool:
        """Whether the vehicle is on the ground (disarmed, or armed but not yet off it)."""
        return self.phase_at(t) == PHASE_LANDED

    def has_arrived(self, target: Position, tolerance_m: float, now_s: float | None = None) -> bool:
        """Whether the last GLOBAL_POSITION_INT is within ``tolerance_m`` of ``target`` in 3-D
        (altitude: relative to home, plus the depot's). ``now_s`` is not used: the telemetry
        is the present."""
        return distance_m(self._position, target) <= tolerance_m

    def distance_m(self, t: float) -> float:
        """Metres flown since the driver started, from telemetry (steps under half a metre,
        GPS jitter, do not count)."""
        return self._distance_m

    def speed_at(self, t: float) -> float:
        """Ground speed in metres a second as the last GLOBAL_POSITION_INT reported it (its
        north and east velocities); 0 on the ground. ``t`` is not used."""
        return self._ground_speed_mps if self._armed else 0.0

    def flight_s(self, t: float) -> float:
        """Seconds flown (armed) up to platform time ``t``."""
        with self._lock:
            since = self._armed_since_s
            if since is None:
                return self._flight_before_s
            return self._flight_before_s + max(0.0, t - since)

    def health(self) -> dict[str, Any]:
        """What an operator sees of the vehicle's health: the link, armed, the flight mode,
        the battery's charge (%), whether the fence is on the autopilot, and the mode a pilot
        or failsafe took it over in (None while the driver is in control)."""
        beat = self.link.heartbeat
        battery = self._battery
        return {
            "link": "up" if self.link_ok else "down",
            "armed": None if beat is None else beat.armed,
            "mode": None if beat is None else beat.mode,
            "battery_pct": None if battery is None else round(battery * 100),
            "fence": "loaded" if self.fence is not None else "none",
            "took_over": self._took_over,
        }

    def battery_fraction(self) -> float | None:
        """The battery's charge 0..1 from SYS_STATUS.battery_remaining (or BATTERY_STATUS),
        None while the vehicle has not reported one."""
        return self._battery

    def battery_remaining_s(self, t: float) -> float | None:
        """Endurance left in seconds: the reported charge times ``spec.battery_s`` (before any
        report: ``battery_s`` minus the flight time). None when ``battery_s`` is unknown."""
        if self.spec.battery_s is None:
            return None
        fraction = self._battery
        if fraction is None:
            return max(0.0, self.spec.battery_s - self.flight_s(t))
        return fraction * self.spec.battery_s

    def time_to_s(self, target: Position, now_s: float) -> float:
        """Estimated seconds for ``fly_to(target)`` from the last known position: a vertical
        take-off first when landed, then one straight leg (the simulator's kinematics). A rover
        or boat turns in place first, from the heading it reports; a sub takes off from
        nowhere."""
        here = self._position
        if not self.flies:
            target = self._reachable(target)
            return self._turn_s(here, target) + self.leg_s(here, target)
        if self.is_landed_at(now_s):
            spec = self.spec
            return from_ground_s(
                here,
                target,
                takeoff_alt_m=spec.takeoff_alt_m,
                speed_mps=spec.max_speed_mps,
                climb_mps=spec.climb_rate_mps,
                descent_mps=spec.descent_rate_mps,
            )
        return self.leg_s(here, target)

    def time_home_s(self, start: Position) -> float:
        """Estimated seconds to return from ``start`` in the air: cruise to above the depot at
        the current altitude (at least the take-off altitude), then land. A rover or boat: a
        half turn at most (its heading then is not known), then the way home; a sub: straight
        up to home at the surface."""
        if not self.flies:
            turn = self.spec.turning_rate_dps
            half_turn_s = 0.0 if turn is None else 180.0 / turn
            return half_turn_s + self.leg_s(start, self.depot)
        above = self.depot.with_alt(max(start.alt, self.spec.takeoff_alt_m, self.depot.alt))
        return self.leg_s(start, above) + self.leg_s(above, self.depot)

    def leg_s(self, a: Position, b: Position) -> float:
        """Estimated seconds of a straight leg in the air (or water) from ``a`` to ``b``: up
        at the climb rate, down at the dive rate (the climb rate without one). No turn."""
        spec = self.spec
        return leg_s(
            a,
            b,
            speed_mps=spec.max_speed_mps,
            climb_mps=spec.climb_rate_mps,
            descent_mps=spec.descent_rate_mps,
        )

    def _turn_s(self, here: Position, target: Position) -> float:
        """A rover's or boat's turn in place towards ``target``, from the heading it last
        reported (none known, or a vehicle that does not turn in place: 0)."""
        rate, heading = self.spec.turning_rate_dps, self._heading_deg
        if rate is None or heading is None or ground_distance_m(here, target) < 0.5:
            return 0.0
        return abs(turn_deg(heading, headings_deg(here, target)[0])) / rate

    # --- flying ---------------------------------------------------------------------------

    def _flavour(self) -> Autopilot:
        autopilot = self.autopilot
        return autopilot if autopilot in _MODES else Autopilot.ARDUPILOT

    def _modes(self, state: str) -> frozenset[str]:
        """The modes the vehicle may show in a state without being overruled."""
        if not self.flies:
            return _KIND_MODES[self.kind][state]
        return _MODES[self._flavour()][state]

    def _check_usable(self, *, returning_ok: bool) -> None:
        if not self.link.link_ok:
            raise LinkLost(f"{self.name}: the link to the vehicle is down")
        if self._resync_due.is_set():  # never a command on what the old connection said
            raise LinkLost(f"{self.name}: the link is back, the vehicle's state not read yet")
        taken = self._took_over
        if taken is not None and not (returning_ok and taken in _RETURN_MODES):
            raise VehicleTookOver(taken)

    def _set_goal(self, modes: frozenset[str]) -> None:
        # While the switch is under way the old mode still shows in heartbeats: allow both
        # until a heartbeat shows one of the new ones (_on_heartbeat narrows it).
        self._allowed_modes = self._goal_modes | modes | {self._mode}
        self._goal_modes = modes

    def _take_off_towards(self, target: Position) -> None:
        here = self._position
        top = here.with_alt(max(target.alt, self.spec.takeoff_alt_m, self.depot.alt + 1.0))
        relative = top.alt - self.depot.alt
        px4 = self.autopilot is Autopilot.PX4
        with self._lock:
            self._state = "takeoff"
            self._target = top
            self._pending = target
            self._set_goal(self._modes("takeoff"))
        try:
            if not px4:
                self.link.set_mode("GUIDED")
            self.link.arm()
        except MavlinkError:
            with self._lock:
                self._state = "idle"
                self._pending = None
            raise
        nan = math.nan
        if px4:
            # PX4 reads the take-off altitude as AMSL, and NaN as "here" for lat/lon/yaw.
            params = (0.0, 0.0, 0.0, nan, nan, nan, self._home_amsl() + relative)
        else:
            params = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, relative)
        try:
            self.link.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, params)
        except MavlinkError:
            with self._lock:
                self._state = "idle"
                self._pending = None
            # Armed motors on the ground are a hazard: disarm (best effort) before reporting.
            try:
                self.link.disarm()
            except MavlinkError as exc:
                logger.warning("%s: could not disarm after a failed take-off: %s", self.name, exc)
            raise
        logger.info("%s: taking off to %.1f m", self.name, relative)
        self._wake.set()

    def _drive_off_towards(self, target: Position) -> None:
        """A rover, boat or sub: GUIDED, armed, then the target (no take-off)."""
        with self._lock:
            armed = self._armed
        if not armed:
            self.link.set_mode("GUIDED")
            self.link.arm()
            logger.info("%s: armed in GUIDED", self.name)
        self._go(target)

    def _stop_here(self, now_s: float) -> float:
        """A rover's or boat's "land now": HOLD; a sub's: SURFACE. The guidance thread
        disarms it once it stands (at the surface). Returns when that is estimated."""
        here = self._position
        depth = max(0.0, self.depot.alt - here.alt)
        eta = now_s + depth / self.spec.climb_rate_mps
        mode = "SURFACE" if self.kind == UNDERWATER else "HOLD"
        with self._lock:
            before = (self._state, self._target, self._pending, self._stream_since)
            self._state = "land"
            self._target = here.with_alt(max(here.alt, self.depot.alt))
            self._pending = None
            self._set_goal(self._modes("land"))
        try:
            self.link.set_mode(mode)
        except MavlinkError:
            with self._lock:  # still doing what it did: say so
                self._state, self._target, self._pending, self._stream_since = before
            raise
        logger.info("%s: stopping where it is (%s)", self.name, mode)
        self._wake.set()
        return eta

    def _go(self, target: Position, *, state: str = "goto") -> None:
        px4 = self.autopilot is Autopilot.PX4
        if not self.flies:
            target = self._reachable(target)
        with self._lock:
            if self._state == "takeoff":
                self._pending = target  # still climbing: go there once up
                return
            self._state = state
            self._target = target
            self._pending = None
            self._set_goal(self._modes(state))
        if px4:
            with self._lock:
                if self._stream_since is None:
                    self._stream_since = time.monotonic()
            self._send_setpoint(target)
        else:
            self.link.set_mode("GUIDED")
            self._send_setpoint(target)
        self._wake.set()

    def _send_setpoint(self, target: Position) -> None:
        px4 = self.autopilot is Autopilot.PX4
        if px4:
            # GLOBAL_INT with an AMSL altitude: what PX4's offboard mode accepts everywhere.
            frame = mavlink.MAV_FRAME_GLOBAL_INT
            alt = self._home_amsl() + (target.alt - self.depot.alt)
        else:
            frame = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
            alt = target.alt - self.depot.alt
        target_system = self.link.target_system or 0
        self.link.send(
            lambda mav: mav.set_position_target_global_int_send(
                0,
                target_system,
                self.link.target_component,
                frame,
                _POSITION_ONLY,
                round(target.lat * 1e7),
                round(target.lng * 1e7),
                alt,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            )
        )
        self._last_setpoint = time.monotonic()

    def _home_amsl(self) -> float:
        """Home's altitude above mean sea level: HOME_POSITION, or GLOBAL_POSITION_INT's
        AMSL minus relative altitude."""
        if self._home_amsl_m is not None:
            return self._home_amsl_m
        msg = self.link.last_message("GLOBAL_POSITION_INT")
        if msg is not None:
            return float(msg.alt - msg.relative_alt) / 1000.0
        raise MavlinkError(f"{self.name}: home altitude unknown (no position yet)")

    def _guidance_loop(self) -> None:
        while not self._stop.is_set():
            px4 = self.autopilot is Autopilot.PX4
            self._wake.wait(1.0 / _PX4_STREAM_HZ if px4 else 0.25)
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                if self._resync_due.is_set():
                    if self.link.link_ok:
                        self._resync()
                    continue
                self._guide(px4)
            except MavlinkError as exc:
                logger.warning("%s: guidance: %s", self.name, exc)
            except Exception:
                logger.exception("%s: guidance", self.name)

    def _guide(self, px4: bool) -> None:
        """One step of what runs in the background: finish the take-off, keep the setpoint
        alive, enter offboard (PX4), disarm a vehicle left armed on the ground (a rover, boat
        or sub once it stands where it was to stop)."""
        now = time.monotonic()
        with self._lock:
            state, target, pending = self._state, self._target, self._pending
            taken = self._took_over
            armed = self._armed
        if not self.link.link_ok:
            return
        if not self.flies and armed and self._stopped_for_good(state, taken):
            logger.info("%s: stopped where it was to: disarming", self.name)
            self.link.disarm()
            return
        if taken is not None:
            return
        if state == "takeoff" and target is not None and self._reached_altitude(target):
            with self._lock:
                self._state = "idle" if pending is None else "goto"
                self._target = pending if pending is not None else target
                self._pending = None
                if pending is not None:
                    self._set_goal(self._modes("goto"))
                    if px4:
                        self._stream_since = now
            if pending is not None:
                self._send_setpoint(pending)
            return
        following = state == "goto" or (state == "return" and self.kind == UNDERWATER)
        if following and target is not None:
            if px4:
                # The guidance also wakes on every position report: keep the stream at 4 Hz.
                if now - self._last_setpoint >= 0.9 / _PX4_STREAM_HZ:
                    self._send_setpoint(target)
                since = self._stream_since
                streaming = since is not None and now - since >= _PX4_OFFBOARD_AFTER_S
                if self._mode != "OFFBOARD" and streaming:
                    self.link.set_mode("OFFBOARD")
            elif now - self._last_setpoint >= _ARDUPILOT_RESEND_S:
                # SET_POSITION_TARGET has no acknowledgement: re-send against packet loss.
                self._send_setpoint(target)
        if state in ("return", "land") and self._armed:
            on_ground = self._landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
            if not on_ground:
                self._on_ground_since = None
            elif self._on_ground_since is None:
                self._on_ground_since = now
            elif now - self._on_ground_since > _STUCK_ARMED_S:
                logger.info("%s: landed but still armed: disarming", self.name)
                self.link.disarm()

    def _stopped_for_good(self, state: str, taken: str | None) -> bool:
        """A rover, boat or sub that stands (at the surface) where it was to stop: at home
        after a return (its own RTL included), anywhere after "land now" (or its own
        SURFACE). ArduRover and ArduSub stay armed there; parked is disarmed."""
        with self._lock:
            here = self._position
            standing = max(self._ground_speed_mps, abs(self._climb_mps)) <= _STANDING_MPS
        if not standing or here.alt < self.depot.alt - _SURFACE_M:
            return False
        home = ground_distance_m(here, self.depot) <= max(
            _LANDING_RADIUS_M, self.arrival_tolerance_m
        )
        if taken is not None:
            return taken == "SURFACE" or (taken in _RETURN_MODES and home)
        return state == "land" or (state == "return" and home)

    def _reachable(self, target: Position) -> Position:
        """Where a rover or boat goes for ``target``: at home's altitude (ArduRover ignores
        altitudes); a sub: no higher than the surface."""
        if self.kind in (GROUND, SURFACE) or target.alt > self.depot.alt:
            return target.with_alt(self.depot.alt)
        return target

    def _reached_altitude(self, top: Position) -> bool:
        # ArduPilot ends its take-off within a few decimetres; a little early is harmless
        # since the cruise leg keeps climbing.
        return self._position.alt >= top.alt - max(0.5, 0.05 * (top.alt - self.depot.alt))

    # --- telemetry (on the link's reader thread) --------------------------------------------

    def _on_heartbeat(self, msg: Any) -> None:
        beat = self.link.heartbeat
        if beat is not None:
            self._on_heartbeat_state(beat.armed, beat.mode)

    def _on_heartbeat_state(self, armed: bool, mode: str) -> None:
        now = self.clock()
        with self._lock:
            self._mode = mode
            if armed and not self._armed:
                self._armed_since_s = now
                self._odometer_anchor = self._position
            elif not armed and self._armed:
                if self._armed_since_s is not None:
                    self._flight_before_s += max(0.0, now - self._armed_since_s)
                self._armed_since_s = None
                self._state = "idle"
                self._target = self._pending = None
                self._took_over = None
                self._stream_since = None
                self._goal_modes = self._allowed_modes = frozenset()
            self._armed = armed
            if not armed or self._state == "idle":
                return
            if mode in self._goal_modes:
                self._allowed_modes = self._goal_modes
            elif mode not in self._allowed_modes and self._took_over is None:
                self._took_over = mode
                self._stream_since = None
                logger.warning("%s: the vehicle switched to %s by itself", self.name, mode)

    def _on_position(self, msg: Any) -> None:
        booted, self._boot_ms = self._boot_ms, int(msg.time_boot_ms)
        if booted is not None and self._boot_ms + 250 < booted:  # uptime went back
            logger.warning(
                "%s: the autopilot restarted (up %.0f s, was %.0f s): resynchronising",
                self.name,
                self._boot_ms / 1000,
                booted / 1000,
            )
            self._resync_due.set()
            self._wake.set()
        if msg.lat == 0 and msg.lon == 0:
            return  # ArduPilot reports 0, 0 until it has a position
        try:
            here = Position(msg.lat / 1e7, msg.lon / 1e7, self.depot.alt + msg.relative_alt / 1000)
        except ValueError:
            return  # out-of-range garbage
        with self._lock:
            self._position = here
            self._ground_speed_mps = math.hypot(msg.vx, msg.vy) / 100  # cm/s
            self._climb_mps = -msg.vz / 100
            self._heading_deg = None if msg.hdg == 65535 else msg.hdg / 100
            self._position_seen_s = self.clock()
            anchor = self._odometer_anchor
            if self._armed and anchor is not None:
                step = distance_m(anchor, here)
                if step >= _ODOMETER_STEP_M:
                    self._distance_m += step
                    self._odometer_anchor = here
        self._wake.set()

    def _on_sys_status(self, msg: Any) -> None:
        if msg.battery_remaining >= 0:  # -1: unknown
            self._battery = msg.battery_remaining / 100.0

    def _on_battery_status(self, msg: Any) -> None:
        if msg.battery_remaining >= 0:
            self._battery = msg.battery_remaining / 100.0

    def _on_extended_state(self, msg: Any) -> None:
        self._landed_state = int(msg.landed_state)

    def _on_home(self, msg: Any) -> None:
        self._home_amsl_m = msg.altitude / 1000.0
        home = Position(msg.latitude / 1e7, msg.longitude / 1e7, self.depot.alt)
        off = ground_distance_m(home, self.depot)
        if off > 20.0:
            logger.warning(
                "%s: the autopilot's home is %.0f m from the depot: altitudes and returns are "
                "relative to it",
                self.name,
                off,
            )

    def _on_link_lost(self) -> None:
        logger.warning("%s: link lost", self.name)
        if self.on_link_lost is not None:
            self.on_link_lost()

    def _on_link_regained(self) -> None:
        logger.warning("%s: link regained: resynchronising", self.name)
        self._resync_due.set()
        self._wake.set()


def _is(kind: str) -> Callable[[Any], bool]:
    return lambda msg: bool(msg.get_type() == kind)


def _text(value: Any) -> str:
    """A MAVLink char[] field as text (pymavlink gives str or bytes, NUL-padded or not)."""
    if isinstance(value, bytes):
        value = value.decode("ascii", errors="replace")
    return str(value).rstrip("\x00")


def _fetch_picture(url: str, timeout_s: float, where: str) -> tuple[bytes, str, int, int]:
    """The picture a camera published at ``url`` (http or https), checked to be a PNG or a
    JPEG: its bytes, format ("png" or "jpeg"), width and height."""
    if urllib.parse.urlsplit(url).scheme not in ("http", "https"):
        raise SensorFailure("the camera gave no picture address", where=f"{where}: {url!r}")
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as answer:
            data = answer.read(_MAX_PICTURE_BYTES + 1)
    except (OSError, ValueError) as exc:
        raise SensorFailure(
            "the camera's picture could not be fetched", where=f"{where}: {url}: {exc}"
        ) from exc
    if len(data) > _MAX_PICTURE_BYTES:
        raise SensorFailure("the camera's picture is too large", where=f"{where}: {url}")
    try:
        with PIL.Image.open(io.BytesIO(data)) as picture:
            fmt, width, height = str(picture.format or "").lower(), picture.width, picture.height
    except (OSError, ValueError) as exc:
        raise SensorFailure(
            "the camera's picture is not an image", where=f"{where}: {url}"
        ) from exc
    if fmt not in ("png", "jpeg"):
        raise SensorFailure(
            f"the camera's picture is {fmt or 'unknown'}, not PNG or JPEG", where=where
        )
    return data, fmt, width, height
