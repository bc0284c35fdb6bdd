"""The MAVLink driver's commands: the driver API's fly_to, return_to_depot, land, recharge."""

from __future__ import annotations

import logging
import math

from fleet.geo import Position
from fleet.kinds import UNDERWATER
from fleet.mavlink.driver_guidance import Guidance
from fleet.mavlink.driver_state import _RETURN_MODES
from fleet.mavlink.errors import (
    CommandDenied,
    LinkLost,
    MavlinkError,
    VehicleTookOver,
)
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.wire import mavlink

logger = logging.getLogger("cpcc.mavlink.driver")


class Flight(Guidance):
    """The commands of the driver API."""

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

    def _check_usable(self, *, returning_ok: bool) -> None:
        if not self.link.link_ok:
            raise LinkLost(f"{self.name}: the link to the vehicle is down")
        if self._resync_due.is_set():  # never a command on what the old connection said
            raise LinkLost(f"{self.name}: the link is back, the vehicle's state not read yet")
        taken = self._took_over
        if taken is not None and not (returning_ok and taken in _RETURN_MODES):
            raise VehicleTookOver(taken)

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
