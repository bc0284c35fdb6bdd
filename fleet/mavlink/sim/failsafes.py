"""What the autopilot checks on every tick and does by itself: the fence (ArduCopter's
Copter::fence_check and FENCE_ACTION), the battery (a warning when low, landing when empty:
ArduPilot's battery failsafe), the ground station gone silent (ArduCopter's GCS failsafe,
FS_GCS_ENABLE and FS_GCS_TIMEOUT; PX4's data link loss, NAV_DLL_ACT and COM_DL_LOSS_T: home),
disarming when armed on the ground too long (DISARM_DELAY, PX4's COM_DISARM_PRFLT) and PX4
leaving offboard when the setpoints stop (COM_OF_LOSS_T).

A rover or boat (ArduRover) takes FS_ACTION on a GCS failsafe (FS_GCS_ENABLE, FS_TIMEOUT: 1 RTL,
2 HOLD, ...) and HOLD where a copter would land; a sub (ArduSub) does what FS_GCS_ENABLE says
(1 warn, 2 disarm, 3 depth hold, 4 surface) and surfaces where a copter would land or return.
Neither disarms by itself."""

from __future__ import annotations

from collections.abc import Callable

from fleet.mavlink.sim.commands import Commander
from fleet.mavlink.sim.fence import LANDING_ACTIONS, REPORT_ONLY, Fence, FenceStatus, fence_names
from fleet.mavlink.sim.flavours import Flavour
from fleet.mavlink.sim.flight import Flight
from fleet.mavlink.sim.messages import LOW_BATTERY, boot_ms
from fleet.mavlink.sim.params import ParamServer
from fleet.mavlink.sim.transport import Build
from fleet.mavlink.wire import mavlink


class Failsafes:
    """The checks of ``commander`` flying ``flight`` (``flavour``: which autopilot's), with
    ``fence`` and the parameters ``params``; ``fence_status`` is what FENCE_STATUS reports.
    ``send`` sends from the autopilot, ``text`` a STATUSTEXT (severity, text), ``wall`` is the
    wall clock."""

    def __init__(
        self,
        commander: Commander,
        flight: Flight,
        fence: Fence,
        params: ParamServer,
        *,
        flavour: Flavour,
        send: Callable[[Build], None],
        text: Callable[[int, str], None],
        wall: Callable[[], float],
        gcs_seen: Callable[[], float | None],
    ) -> None:
        self._commander = commander
        self._flight = flight
        self._fence = fence
        self._params = params
        self._flavour = flavour
        self._send = send
        self._text = text
        self._wall = wall
        self._gcs_seen = gcs_seen
        self.fence_status = FenceStatus()
        self.gcs_failsafe = False  # on since the ground station went silent

    def check(self) -> None:
        now = self._flight.now()
        self._check_fence(now)
        self._check_battery(now)
        self._check_gcs(now)
        self._check_auto_disarm()
        self._check_setpoint_stream()

    def _check_fence(self, now: float) -> None:
        """A fence breach while flying: FENCE_STATUS, "Polygon fence breached" and the
        FENCE_ACTION."""
        flight, status = self._flight, self.fence_status
        if not self._commander.armed or flight.on_ground or flight.stage == "landing":
            return  # ArduCopter never acts on a breach in the final stage of landing either
        breaches = self._fence.breaches(flight.position_at(now))
        if breaches == status.breaches:
            return
        new = status.update(breaches, boot_ms(self._wall()))
        if new:
            self._text(mavlink.MAV_SEVERITY_NOTICE, f"{fence_names(new)} breached")
        self._send(status.send)
        if new:
            self._fence_action()

    def _fence_action(self) -> None:
        f, commander = self._flavour, self._commander
        action = round(self._params.get("FENCE_ACTION", REPORT_ONLY))
        if action == REPORT_ONLY or commander.mode == f.land:
            return
        if action in LANDING_ACTIONS or f.rtl is None:
            commander.change_mode(f.land)
        elif (
            commander.mode != f.rtl and commander.change_mode(f.rtl) != mavlink.MAV_RESULT_ACCEPTED
        ):
            commander.change_mode(f.land)  # RTL or, when that fails, land

    def _check_battery(self, now: float) -> None:
        flight = self._flight
        fraction = flight.battery(now)
        if fraction < LOW_BATTERY and not flight.battery_warned and not flight.on_ground:
            flight.battery_warned = True
            self._text(mavlink.MAV_SEVERITY_WARNING, "Battery 1 is low")
        if fraction <= 0.0 and not flight.on_ground and flight.stage != "landing":
            # ArduPilot's critical battery failsafe: land where it is.
            flight.battery_failsafe = True
            self._text(mavlink.MAV_SEVERITY_CRITICAL, "Battery 1 is critical: landing")
            self._commander.land_now(now)

    def _check_gcs(self, now: float) -> None:
        """No heartbeat from a ground station for the timeout, with the failsafe on and a
        ground station heard before: an armed vehicle in the air returns home (one on the
        ground disarms), once; heartbeats again clear it (the vehicle keeps returning)."""
        f, commander, flight = self._flavour, self._commander, self._flight
        enable, timeout = f.gcs_failsafe_params
        seen = self._gcs_seen()
        if not self._params.value(enable) or seen is None:
            return
        silent = self._wall() - seen > self._params.value(timeout)
        if not silent:
            if self.gcs_failsafe:
                self.gcs_failsafe = False
                self._text(mavlink.MAV_SEVERITY_INFO, "GCS Failsafe Cleared")
            return
        if self.gcs_failsafe or not commander.armed:
            return
        self.gcs_failsafe = True
        self._text(mavlink.MAV_SEVERITY_CRITICAL, "GCS Failsafe")
        if not f.takes_off:
            self._gcs_failsafe_action()
        elif flight.on_ground:
            commander.stop_motors()
        elif commander.mode not in (f.rtl, f.land) and (
            commander.change_mode(f.rtl or f.land) != mavlink.MAV_RESULT_ACCEPTED
        ):
            commander.change_mode(f.land)

    def _gcs_failsafe_action(self) -> None:
        """What ArduRover (FS_ACTION) and ArduSub (FS_GCS_ENABLE) do when the GCS is gone."""
        f, commander = self._flavour, self._commander
        if f.rtl is None:  # ArduSub
            action = round(self._params.value("FS_GCS_ENABLE"))
            if action == 2:
                commander.execute(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (0.0,) * 7, 0)
            elif action in (3, 4):
                commander.change_mode("ALT_HOLD" if action == 3 else f.land)
            return
        action = round(self._params.get("FS_ACTION", 2))
        if action in (1, 3):  # RTL (SmartRTL is not simulated)
            commander.change_mode(f.rtl or f.land)
        elif action != 0:
            commander.change_mode(f.land)  # HOLD

    def _check_auto_disarm(self) -> None:
        commander = self._commander
        if self._flavour.disarm_delay_param is None:
            return
        delay = self._params.value(self._flavour.disarm_delay_param)
        if (
            commander.armed
            and self._flight.on_ground
            and delay > 0
            and self._wall() - commander.armed_wall > delay
        ):
            # Armed on the ground without taking off: disarm after the delay, as ArduPilot
            # does (a safety timer on the wall clock, not flight time).
            commander.stop_motors()

    def _check_setpoint_stream(self) -> None:
        f, commander = self._flavour, self._commander
        if not f.setpoint_stream or commander.mode != f.follows_targets:
            return
        if commander.guided.setpoints.lost():
            # PX4 leaves offboard when the setpoints stop and holds.
            self._text(mavlink.MAV_SEVERITY_WARNING, "Offboard lost: holding position")
            commander.change_mode("AUTO.LOITER")
