"""The MAVLink driver's guidance: the modes it asks for and the loop that sends setpoints and
watches the flight."""

from __future__ import annotations

import logging
import time

from fleet.geo import Position, ground_distance_m
from fleet.kinds import UNDERWATER
from fleet.mavlink.driver_sensors import Sensors
from fleet.mavlink.driver_state import (
    _ARDUPILOT_RESEND_S,
    _LANDING_RADIUS_M,
    _POSITION_ONLY,
    _PX4_OFFBOARD_AFTER_S,
    _PX4_STREAM_HZ,
    _RETURN_MODES,
    _STANDING_MPS,
    _STUCK_ARMED_S,
    _SURFACE_M,
)
from fleet.mavlink.errors import MavlinkError
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.wire import mavlink

logger = logging.getLogger("cpcc.mavlink.driver")


class Guidance(Sensors):
    """The modes and the guidance loop (setpoints, take-off, return, disarming)."""

    def _set_goal(self, modes: frozenset[str]) -> None:
        # While the switch is under way the old mode still shows in heartbeats: allow both
        # until a heartbeat shows one of the new ones (_on_heartbeat narrows it).
        self._allowed_modes = self._goal_modes | modes | {self._mode}
        self._goal_modes = modes

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

    def _resync(self) -> None:
        """After the link came back or the autopilot restarted: read the vehicle's state afresh
        and set it up again (``MavlinkDriver``, which connects and sets up)."""
        raise NotImplementedError

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

    def _reached_altitude(self, top: Position) -> bool:
        # ArduPilot ends its take-off within a few decimetres; a little early is harmless
        # since the cruise leg keeps climbing.
        return self._position.alt >= top.alt - max(0.5, 0.05 * (top.alt - self.depot.alt))
