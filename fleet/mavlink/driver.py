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

``flight_log`` (a ``fleet.mavlink.tlog.TlogRecorder``) records the link's messages both ways
as a ``.tlog`` between its ``start()`` (the worker calls it at the take-off) and its
``finish()`` (at the landing), time-stamped by the wall clock as a ground station's log is.

The driver is built in parts by sub-protocol, each on the ones before it: ``driver_state``
(the state every part shares, the constants), ``driver_telemetry`` (the link's reader thread
and the driver API's queries), ``driver_sensors`` (readings and the camera protocol),
``driver_guidance`` (modes and the setpoint loop), ``driver_flight`` (the API's commands),
and here connecting, the vehicle's set-up (streams, GCS failsafe) and the fence and rally
upload.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

from fleet.geo import Position
from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER, a_vehicle, limits_of
from fleet.mavlink.driver_flight import Flight
from fleet.mavlink.driver_state import Fence
from fleet.mavlink.errors import (
    MavlinkError,
    UnsupportedVehicle,
)
from fleet.mavlink.mission import exclusion_polygons, fence_polygon_items, rally_items
from fleet.mavlink.modes import KIND_OF_TYPE, KIND_WORDS, Autopilot
from fleet.mavlink.wire import mavlink

logger = logging.getLogger("cpcc.mavlink.driver")

__all__ = ["Fence", "MavlinkDriver"]


class MavlinkDriver(Flight):
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
