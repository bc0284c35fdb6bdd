"""The MAVLink driver's telemetry: what the link's reader thread hears, and the driver API's
queries answered from it."""

from __future__ import annotations

import logging
import math
from typing import Any

from fleet.geo import Position, distance_m, ground_distance_m, headings_deg, turn_deg
from fleet.mavlink.driver_state import (
    _LANDING_RADIUS_M,
    _ODOMETER_STEP_M,
    _RETURN_MODES,
    _STANDING_MPS,
    _SURFACE_M,
    DriverState,
)
from fleet.mavlink.wire import mavlink
from fleet.simulation.vehicle import (
    PHASE_CRUISE,
    PHASE_HOVERING,
    PHASE_LANDED,
    PHASE_LANDING,
    PHASE_TAKEOFF,
)

logger = logging.getLogger("cpcc.mavlink.driver")


class Telemetry(DriverState):
    """The telemetry handlers (on the link's reader thread) and the queries of the driver API."""

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
            return self.spec.from_ground_s(here, target)
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
        return self.spec.leg_s(a, b)

    def _turn_s(self, here: Position, target: Position) -> float:
        """A rover's or boat's turn in place towards ``target``, from the heading it last
        reported (none known, or a vehicle that does not turn in place: 0)."""
        rate, heading = self.spec.turning_rate_dps, self._heading_deg
        if rate is None or heading is None or ground_distance_m(here, target) < 0.5:
            return 0.0
        return abs(turn_deg(heading, headings_deg(here, target)[0])) / rate
