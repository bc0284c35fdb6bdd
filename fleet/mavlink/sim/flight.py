"""The vehicle's flight (or drive, or dive): where it is and what manoeuvre it makes, on the
simulated clock.

``Flight`` moves a ``fleet.simulation.SimVehicle`` of the spec's kind (a copter's vertical
take-off, straight legs and vertical landing; a rover's or boat's turns and legs in the plane;
a sub's dives and rises: exactly the in-process simulator's kinematics) and drains the battery
over the time it is under way; it knows nothing of modes or MAVLink. For a vehicle that does
not fly, "on the ground" means parked (not under way): it leaves that state with its first
leg and comes back to it at the end of a return or a stop ("landing" is stopping there, a sub
rising to the surface). ``Pilot`` is that flight as AUTO and GUIDED fly it,
with the autopilot's arming and modes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

from fleet.geo import Position, distance_m
from fleet.kinds import AERIAL, UNDERWATER, limits_of
from fleet.mavlink.mission import MissionItem
from fleet.mavlink.sim.targets import global_target
from fleet.simulation.vehicle import SimVehicle, VehicleSpec

_SAME_TARGET_M = 1e-3  # a guided target this close to the last one is the same again

# What ``Flight.advance`` reports.
TOOK_OFF = "took off"
LANDED = "landed"


def velocity_ned(here: Position, ahead: Position, dt_s: float) -> tuple[float, float, float]:
    """North, east, down in m/s between two positions ``dt_s`` apart (small distances)."""
    m_per_deg = 111_320.0
    north = (ahead.lat - here.lat) * m_per_deg / dt_s
    east = (ahead.lng - here.lng) * m_per_deg * math.cos(math.radians(here.lat)) / dt_s
    down = -(ahead.alt - here.alt) / dt_s
    return north, east, down


class Flight:
    """The airframe ``spec`` flying from ``home``, where it starts landed (parked).

    The simulated clock runs ``speed`` times the wall clock ``wall`` (seconds since boot); at
    speed 0 it stands at the end of whatever is planned, so every manoeuvre ends at once.
    ``battery`` is the charge it starts with (0..1), ``return_alt`` the altitude above home it
    returns at (at least; a parameter, read when the return begins; an aircraft's only).
    """

    def __init__(
        self,
        spec: VehicleSpec,
        home: Position,
        *,
        speed: float,
        wall: Callable[[], float],
        battery: float,
        return_alt: Callable[[], float],
    ) -> None:
        self.spec = spec
        self.home = home
        self.takes_off = spec.kind == AERIAL
        self._speed = speed
        self._wall = wall
        self._return_alt = return_alt
        self._instant_t = 0.0  # speed 0: the simulated clock, moved to each plan's end
        self._vehicle = SimVehicle(spec, home, now_s=0.0)
        self._flown_before_s = 0.0  # flight time of the SimVehicles replaced on touchdown
        self.on_ground = True
        # What it is doing: "takeoff", "goto" (a target, then hovering there), "hover" (a
        # mission's hold time), "return" and "approach" (then "landing"), or None (landed or
        # holding where it is).
        self.stage: str | None = None
        self.stage_end_s = 0.0
        self._target: Position | None = None
        self._battery_base = min(1.0, max(0.0, battery))
        self._battery_base_used_s = 0.0
        self.battery_warned = False  # "Battery 1 is low" said
        self.battery_failsafe = False  # landing on an empty battery

    # --- the clock and where it is ----------------------------------------------------------

    def now(self) -> float:
        """The simulated clock, in seconds since boot."""
        if self._speed > 0:
            return self._wall() * self._speed
        # Instant flights: the simulated clock stands at the end of whatever is planned.
        plan_end = self._vehicle.plan_end_s
        if self.stage is not None:
            plan_end = max(plan_end, self.stage_end_s)
        self._instant_t = max(self._instant_t, plan_end)
        return self._instant_t

    def position_at(self, t: float) -> Position:
        return self._vehicle.position_at(t)

    def here(self) -> Position:
        return self._vehicle.position_at(self.now())

    def where(self) -> tuple[Position, float]:
        """Where it is, and the simulated time."""
        now = self.now()
        return self._vehicle.position_at(now), now

    def velocity(self, now: float) -> tuple[float, float, float]:
        """North, east, down in m/s: the plan's next simulated tenth of a second."""
        ahead = self._vehicle.position_at(now + 0.1)
        return velocity_ned(self._vehicle.position_at(now), ahead, 0.1)

    def heading_deg(self, now: float) -> float | None:
        """The direction of travel, or None when it hovers or stands."""
        north, east, _ = self.velocity(now)
        if math.hypot(north, east) <= 0.1:
            return None
        return math.degrees(math.atan2(east, north)) % 360

    def idle(self) -> bool:
        """No manoeuvre under way: landed, or hovering (a target reached, a wait over)."""
        now = self.now()
        return self.stage is None or (self.stage in ("goto", "hover") and now >= self.stage_end_s)

    def set_speed(self, field: str, mps: float) -> None:
        """Change a speed of the spec (``max_speed_mps``, ``climb_rate_mps``) from the next leg
        on."""
        changes: dict[str, Any] = {field: mps}
        self.spec = replace(self.spec, **changes)
        self._vehicle.spec = self.spec

    # --- manoeuvres -------------------------------------------------------------------------

    def lift_off(self, above_ground: float) -> None:
        now = self.now()
        top = self._vehicle.position_at(now).with_alt(above_ground)
        self.on_ground = False
        self._fly(top, "takeoff", now)

    def climb_to(self, alt: float) -> None:
        """Take off (or climb where it is) to ``alt`` metres above ground."""
        if self.on_ground:
            self.lift_off(alt)
            return
        now = self.now()
        self._fly(self._vehicle.position_at(now).with_alt(alt), "goto", now)

    def go_to(self, target: Position) -> None:
        """Fly straight to ``target`` and hover there. A rover or boat goes to it in the plane
        (the autopilot ignores a target's altitude), a sub no higher than the surface."""
        target = self.reachable(target)
        same = self._target is not None and distance_m(target, self._target) < _SAME_TARGET_M
        if same and self.stage == "goto":
            return  # the same target again (targets are re-sent against packet loss)
        self._fly(target, "goto", self.now())

    def reachable(self, target: Position) -> Position:
        """Where the vehicle's kind goes for ``target``: a rover or boat at home's altitude, a
        sub at most at the surface, an aircraft there."""
        if not limits_of(self.spec.kind).vertical:
            return target.with_alt(self.home.alt)
        if self.spec.kind == UNDERWATER and target.alt > self.home.alt:
            return target.with_alt(self.home.alt)
        return target

    def hover_for(self, seconds: float) -> None:
        """Stay where it is for ``seconds`` of simulated time."""
        now = self.now()
        self.hold(now)
        # A stage with an end: the instant clock (speed 0) moves on to it as to any other.
        self.stage = "hover"
        self.stage_end_s = now + seconds

    def hold(self, now: float) -> None:
        """Stop where it is and hover there."""
        here = self._vehicle.position_at(now)
        self._vehicle.fly_to(here, now)
        self._target = here
        self.stage = None

    def start_return(self, now: float) -> None:
        # As SimVehicle.return_to_depot: cruise home at the current altitude (at least the
        # return altitude), then land vertically.
        here = self._vehicle.position_at(now)
        rtl_alt = self.home.alt + self._return_alt()
        self._fly(self.home.with_alt(max(here.alt, rtl_alt, self.home.alt)), "return", now)

    def start_approach(self, spot: Position, now: float) -> None:
        """Fly to above ``spot`` at the altitude it is at, then land (NAV_LAND at a place)."""
        here = self._vehicle.position_at(now)
        self._fly(spot.with_alt(here.alt), "approach", now)

    def start_landing(self, now: float) -> None:
        here = self._vehicle.position_at(now)
        self._fly(here.with_alt(self.home.alt), "landing", now)

    def touchdown(self, at: float) -> None:
        """On the ground at ``at`` (parked, for a vehicle that does not fly; a sub parks at
        the surface): the flight's SimVehicle is retired, a new one stands here."""
        spot = self._vehicle.position_at(at).with_alt(self.home.alt)
        self._flown_before_s += self._vehicle.flight_s(at)
        self._vehicle = SimVehicle(self.spec, spot, now_s=at)
        self.on_ground = True
        self.stage = None
        self._target = None

    def advance(self) -> str | None:
        """End the manoeuvres whose time has come: TOOK_OFF when a take-off just ended,
        LANDED on touchdown (a return or an approach lands first), else None."""
        now = self.now()
        if self.stage == "takeoff" and now >= self.stage_end_s:
            self.stage = None
            return TOOK_OFF
        if self.stage in ("return", "approach") and now >= self.stage_end_s:
            self.start_landing(self.stage_end_s)
            now = self.now()
        if self.stage == "landing" and now >= self.stage_end_s:
            self.touchdown(self.stage_end_s)
            return LANDED
        return None

    def _fly(self, target: Position, stage: str, now: float) -> None:
        if not self.takes_off and stage != "landing":
            self.on_ground = False  # under way: no take-off first
        self._target = target
        self.stage = stage
        self.stage_end_s = self._vehicle.fly_to(target, now)

    # --- the battery ------------------------------------------------------------------------

    def used_s(self, now: float) -> float:
        """Simulated seconds flown since boot."""
        return self._flown_before_s + self._vehicle.flight_s(now)

    def battery(self, now: float) -> float:
        """The charge at ``now``, 0..1 (it never drains without ``spec.battery_s``)."""
        battery_s = self.spec.battery_s
        if battery_s is None:
            return self._battery_base
        drained = (self.used_s(now) - self._battery_base_used_s) / battery_s
        return min(1.0, max(0.0, self._battery_base - drained))

    def reset_battery(self, fraction: float) -> None:
        """A fresh battery with this charge (0..1) is in."""
        self._battery_base = min(1.0, max(0.0, fraction))
        self._battery_base_used_s = self.used_s(self.now())
        self.battery_warned = False
        self.battery_failsafe = False


class Controls(Protocol):
    """The autopilot's arming and modes, as the pilot needs them (``commands.Commander``)."""

    @property
    def armed(self) -> bool: ...

    @property
    def mode(self) -> str: ...

    def change_mode(self, mode: str) -> int:
        """Switch modes; the MAV_RESULT."""
        ...


class Pilot:
    """The flight as AUTO and GUIDED fly it (``auto.Flight``, ``guided.Vehicle``): the
    manoeuvres of ``flight`` with the arming and modes of ``controls``; ``ground_amsl_m`` is
    what AMSL altitudes are measured from."""

    def __init__(self, flight: Flight, controls: Controls, *, ground_amsl_m: float) -> None:
        self._flight = flight
        self._controls = controls
        self._ground_amsl_m = ground_amsl_m

    @property
    def on_ground(self) -> bool:
        return self._flight.on_ground

    @property
    def armed(self) -> bool:
        return self._controls.armed

    @property
    def mode(self) -> str:
        return self._controls.mode

    def change_mode(self, mode: str) -> int:
        return self._controls.change_mode(mode)

    def idle(self) -> bool:
        return self._flight.idle()

    def here(self) -> Position:
        return self._flight.here()

    def item_target(self, item: MissionItem) -> Position:
        here = self.here()
        lat, lng = (here.lat, here.lng) if item.x == 0 and item.y == 0 else (item.lat, item.lng)
        return global_target(
            item.frame, lat, lng, item.z, home=self._flight.home, ground_amsl_m=self._ground_amsl_m
        )

    def climb_to(self, alt: float) -> None:
        self._flight.climb_to(alt)

    def go_to(self, target: Position) -> None:
        self._flight.go_to(target)

    def hover_for(self, seconds: float) -> None:
        self._flight.hover_for(seconds)

    def return_home(self) -> None:
        self._flight.start_return(self._flight.now())

    def land_at(self, spot: Position) -> None:
        self._flight.start_approach(spot, self._flight.now())
