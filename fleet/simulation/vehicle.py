"""Kinematic simulation of one unmanned vehicle: take-off, straight legs, hovering, landing.

Pure Python (no Django). Time is whatever clock the caller uses, in seconds; the vehicle never
reads a clock itself. A ``SimVehicle`` keeps its whole flown history as a list of straight legs,
so every query (position, phase, odometry, flight time, battery) can be answered for any time,
past or planned, and the same sequence of commands always gives the same answers.

How it moves depends on its kind (``fleet.kinds``). An aerial vehicle (a copter) takes off
vertically, flies straight legs and lands vertically. Ground and surface vehicles (rovers,
boats) stay at their depot's altitude (their home: 0), never take off, and turn in place
before each straight leg ("turning" legs of no length). An underwater vehicle starts at the
surface at its depot, dives and rises along its legs (below its depot's altitude is depth),
and surfaces to be parked. The vehicle's own "landed" means parked: on the ground, at the
dock, or stopped by ``land``; "hovering" means stopped on the way.

Commands (``fly_to``, ``return_to_depot``) replace the rest of the plan from the command's time
on; a leg that is under way is cut at that time and the vehicle continues from where it is.
Commands must come in non-decreasing time order, otherwise ``ValueError`` is raised.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

from fleet.driving import Sample, SensorFailure, SensorRead
from fleet.geo import (
    Position,
    distance_m,
    ground_distance_m,
    headings_deg,
    interpolate,
    turn_deg,
)
from fleet.kinds import AERIAL, UNDERWATER, limits_of
from fleet.kinematics import from_ground_s, leg_s, take_off_top

PHASE_LANDED = "landed"
PHASE_TAKEOFF = "takeoff"
PHASE_CRUISE = "cruise"
PHASE_LANDING = "landing"
PHASE_HOVERING = "hovering"
PHASE_TURNING = "turning"  # a ground or surface vehicle turning in place before a leg


# Floating-point slack of an arrival exactly at the planned time.
_ARRIVAL_SLACK_M = 1e-3
# A turn smaller than this (geodesic rounding) is not made.
_TURN_SLACK_DEG = 1e-6
# Headings where there is none yet: a new vehicle faces north.
_NORTH_DEG = 0.0


def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True)
class VehicleSpec:
    """What the simulated vehicle can do.

    ``max_speed_mps``: horizontal cruise speed (> 0). ``climb_rate_mps``: vertical speed for
    take-off, climbing, descending and landing (> 0). ``takeoff_alt_m``: height above ground an
    aerial vehicle climbs to at least before leaving its take-off point (>= 0; the other kinds
    take off from nowhere). ``battery_s``: endurance in seconds (> 0), or None for unlimited.
    ``kind``: one of ``fleet.kinds.KINDS``. ``dive_rate_mps``: vertical speed going down
    (> 0), or None for the climb rate. ``turn_rate_dps``: how fast a ground or surface vehicle
    turns in place, degrees a second (> 0), or None for its kind's default; the other kinds
    ignore it. Raises ValueError on a bad value, naming the field.
    """

    max_speed_mps: float
    climb_rate_mps: float = 3.0
    takeoff_alt_m: float = 5.0
    battery_s: float | None = None
    kind: str = AERIAL
    dive_rate_mps: float | None = None
    turn_rate_dps: float | None = None

    def __post_init__(self) -> None:
        limits_of(self.kind)
        _check_positive("max_speed_mps", self.max_speed_mps)
        _check_positive("climb_rate_mps", self.climb_rate_mps)
        if not (math.isfinite(self.takeoff_alt_m) and self.takeoff_alt_m >= 0.0):
            raise ValueError(
                f"takeoff_alt_m must be a non-negative finite number, got {self.takeoff_alt_m!r}"
            )
        if self.battery_s is not None:
            _check_positive("battery_s", self.battery_s)
        if self.dive_rate_mps is not None:
            _check_positive("dive_rate_mps", self.dive_rate_mps)
        if self.turn_rate_dps is not None:
            _check_positive("turn_rate_dps", self.turn_rate_dps)

    @property
    def descent_rate_mps(self) -> float:
        """Vertical speed going down: the dive rate, else the climb rate."""
        return self.climb_rate_mps if self.dive_rate_mps is None else self.dive_rate_mps

    def leg_s(self, start: Position, end: Position) -> float:
        """Seconds of a straight leg at this vehicle's rates (``fleet.kinematics.leg_s``)."""
        return leg_s(
            start,
            end,
            speed_mps=self.max_speed_mps,
            climb_mps=self.climb_rate_mps,
            descent_mps=self.descent_rate_mps,
        )

    def from_ground_s(self, here: Position, target: Position) -> float:
        """Seconds from the ground at ``here`` to ``target``: the take-off to this vehicle's
        take-off altitude, then the leg (``fleet.kinematics.from_ground_s``)."""
        return from_ground_s(
            here,
            target,
            takeoff_alt_m=self.takeoff_alt_m,
            speed_mps=self.max_speed_mps,
            climb_mps=self.climb_rate_mps,
            descent_mps=self.descent_rate_mps,
        )

    @property
    def turning_rate_dps(self) -> float | None:
        """How fast the vehicle turns in place before a leg (None: it turns as it moves, at
        no cost, as aerial and underwater vehicles do)."""
        default = limits_of(self.kind).turn_rate_dps
        if default is None:
            return None
        return default if self.turn_rate_dps is None else self.turn_rate_dps


@dataclass(frozen=True)
class Leg:
    """One straight segment of a flight plan, flown at constant velocity from start to end.

    ``phase`` is "takeoff", "cruise", "turning" (in place: ``start == end``) or "landing".
    ``start_s``/``end_s`` are on the caller's clock.
    """

    start_s: float
    end_s: float
    start: Position
    end: Position
    phase: str

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def position_at(self, t: float) -> Position:
        """Where the vehicle is at time t on this leg (clamped to the leg's ends)."""
        if self.end_s <= self.start_s or t >= self.end_s:
            return self.end
        if t <= self.start_s:
            return self.start
        return interpolate(self.start, self.end, (t - self.start_s) / (self.end_s - self.start_s))


@dataclass(frozen=True)
class _Step:
    """A leg of the history plus the running totals that make queries O(log n), and the
    headings at its ends (kept for vehicles that turn in place; 0 for the others)."""

    leg: Leg
    length_m: float
    landed_after: bool
    distance_before_m: float
    flight_before_s: float
    heading_from_deg: float = _NORTH_DEG
    heading_to_deg: float = _NORTH_DEG


class SimVehicle:
    """A simulated vehicle that starts landed at its depot and flies straight legs.

    ``spec`` says how fast it flies and its kind, ``depot`` where it takes off and lands (for
    ground and surface vehicles also the altitude they move at; for an underwater vehicle the
    surface), ``now_s`` the time it comes into existence (no command may be earlier). Queries
    before the first command answer "landed at the depot".
    """

    def __init__(self, spec: VehicleSpec, depot: Position, *, now_s: float = 0.0) -> None:
        if not math.isfinite(now_s):
            raise ValueError(f"now_s must be a finite number, got {now_s!r}")
        self.spec = spec
        self.depot = depot
        self.measures_battery = False  # its battery is the time it has flown
        self.reports_arrival = False  # it is where the kinematics say, when they say
        self._command_s = now_s
        self._steps: list[_Step] = []
        # Parallel list of leg start times, kept for bisect.
        self._starts: list[float] = []
        # Finished charges: (when the battery was full again, flight time by then).
        self._charges: list[tuple[float, float]] = []

    @property
    def last_command_s(self) -> float:
        """Time of the last command (or of creation); later commands must not be earlier."""
        return self._command_s

    @property
    def plan_end_s(self) -> float:
        """When the current plan is done (the last command's time if nothing is planned)."""
        if not self._steps:
            return self._command_s
        return max(self._command_s, self._steps[-1].leg.end_s)

    @property
    def _in_plane(self) -> bool:
        """A ground or surface vehicle: it stays at its depot's altitude."""
        return not limits_of(self.spec.kind).vertical

    @property
    def _submerges(self) -> bool:
        return self.spec.kind == UNDERWATER

    # Commands

    def fly_to(self, target: Position, now_s: float) -> float:
        """Plan a flight from wherever the vehicle is at ``now_s`` to ``target``.

        Replaces the rest of the plan. An aerial vehicle, from landed: a vertical take-off to
        ``max(target.alt, takeoff_alt_m)``, then one straight cruise leg; airborne: one
        straight cruise leg. A leg lasts ``max(horizontal / max_speed, vertical / rate)`` (the
        climb rate going up, the dive rate going down), so the vehicle arrives exactly at
        ``target``. An underwater vehicle needs no take-off: it dives along its one leg. A
        ground or surface vehicle first turns in place from its heading (that of its last
        leg; north when new) to the leg's, at its turn rate, then drives the leg.

        Returns the arrival time (``now_s`` if already there). Raises ValueError if ``now_s``
        is not finite or earlier than the last command, or the target is where the kind
        cannot go: for a ground or surface vehicle any altitude but its depot's, for an
        underwater one above the surface (the plan is then unchanged).
        """
        target = self._reachable(target)
        here, landed = self._begin_command(now_s)
        if here == target:
            return now_s
        t = now_s
        if self._in_plane:
            t = self._turn(t, here, target)
        elif landed and not self._submerges:
            top = take_off_top(here, target, takeoff_alt_m=self.spec.takeoff_alt_m)
            if top.alt > here.alt:
                t = self._append(t, here, top, PHASE_TAKEOFF)
                here = top
        return self._append(t, here, target, PHASE_CRUISE)

    def hover_at(self, position: Position, now_s: float) -> None:
        """Start in the air: at ``now_s`` the vehicle hovers at ``position`` (above its depot's
        altitude), as one that was flying when its simulation began; the next command flies
        from there without a take-off. Only before any other command. Raises ValueError
        otherwise, for a vehicle that does not fly, or for a position not above the depot."""
        if self._steps:
            raise ValueError("a vehicle starts in the air only before its first command")
        if self.spec.kind != AERIAL or position.alt <= self.depot.alt:
            raise ValueError(
                f"only an aerial vehicle hovers, above its depot's {self.depot.alt:g} m"
            )
        self._begin_command(now_s)
        self._append(now_s, position, position, PHASE_HOVERING, duration_s=0.0)

    def return_to_depot(self, now_s: float) -> float:
        """Plan the way home: cruise to above the depot, then land vertically on it.

        Replaces the rest of the plan. The cruise keeps the current altitude (at least
        ``takeoff_alt_m``); the landing leg ends at the depot, after which the vehicle is landed.
        A ground or surface vehicle turns and drives to the depot and stops there. An
        underwater vehicle rises straight up to the surface where it is, then cruises on the
        surface to the depot and docks (it never travels submerged towards a dock it cannot
        see, and a vehicle at the surface is the one an operator can find). Both end with a
        landing leg of no length, which marks them landed. Returns the landing time
        (``now_s`` if already landed). Raises ValueError like ``fly_to``.
        """
        here, landed = self._begin_command(now_s)
        if landed:
            return now_s
        if self._in_plane or self._submerges:
            t = now_s
            surface = here.with_alt(self.depot.alt)
            if here != surface:
                t = self._append(t, here, surface, PHASE_CRUISE)
            if surface != self.depot:
                if self._in_plane:
                    t = self._turn(t, surface, self.depot)
                t = self._append(t, surface, self.depot, PHASE_CRUISE)
            return self._append(t, self.depot, self.depot, PHASE_LANDING, landed_after=True)
        cruise_alt = max(here.alt, self.spec.takeoff_alt_m, self.depot.alt)
        above = self.depot.with_alt(cruise_alt)
        t = now_s
        if here != above:
            t = self._append(t, here, above, PHASE_CRUISE)
        # Appended even with zero length: it is what marks the vehicle as landed.
        return self._append(t, above, self.depot, PHASE_LANDING, landed_after=True)

    def land(self, now_s: float) -> float:
        """Plan a landing where the vehicle is: straight down to the depot's height (altitudes
        are above ground, as the autopilot's are relative to its home). A ground or surface
        vehicle stops where it is; an underwater vehicle rises straight up to the surface
        (phase "landing") and stays there.

        Replaces the rest of the plan; afterwards the vehicle is landed there, and a later
        ``fly_to`` takes off from there. Returns the touchdown time (``now_s`` if already
        landed). Raises ValueError like ``fly_to``.
        """
        here, landed = self._begin_command(now_s)
        if landed:
            return now_s
        # Appended even with zero length: it is what marks the vehicle as landed.
        ground = here.with_alt(self.depot.alt)
        return self._append(now_s, here, ground, PHASE_LANDING, landed_after=True)

    def recharge(self, now_s: float, duration_s: float) -> float:
        """Charge the battery on the ground: full again ``duration_s`` after ``now_s``.

        Returns when it is full. Raises ValueError when the vehicle is not landed at ``now_s``
        or the duration is negative; commands after ``now_s`` stay allowed (a vehicle that
        takes off before the end is simply not charged).
        """
        if not self.is_landed_at(now_s):
            raise ValueError(f"the vehicle is not landed at {now_s!r} s: it cannot charge")
        if duration_s < 0 or not math.isfinite(duration_s):
            raise ValueError(f"duration_s must be a finite number >= 0, got {duration_s!r}")
        done_s = now_s + duration_s
        self._charges.append((done_s, self.flight_s(now_s)))
        return done_s

    def has_arrived(self, target: Position, tolerance_m: float, now_s: float) -> bool:
        """Whether the vehicle is within ``tolerance_m`` (3-D) of ``target`` at ``now_s``."""
        return distance_m(self.position_at(now_s), target) <= tolerance_m + _ARRIVAL_SLACK_M

    # Estimates (the plan is not changed)

    def time_to_s(self, target: Position, now_s: float) -> float:
        """How long ``fly_to(target, now_s)`` would take from where the vehicle is then (for a
        ground or surface vehicle with its turn from its heading then)."""
        here = self.position_at(now_s)
        seconds = 0.0
        if self._in_plane:
            seconds += self._turn_s(self._heading_at(now_s), here, target)
        elif self.is_landed_at(now_s) and not self._submerges:
            return self.spec.from_ground_s(here, target)
        return seconds + self._duration(here, target)

    def time_home_s(self, start: Position) -> float:
        """How long ``return_to_depot`` would take from ``start`` in the air: cruise to above
        the depot, then land. A ground or surface vehicle's heading at ``start`` is not known:
        its turn is counted as half a turn, the most it can be (an estimate that errs on the
        safe side, as a battery's reserve wants). An underwater vehicle's: surface, then
        cruise home."""
        if self._in_plane:
            half_turn_s = 180.0 / self._turn_rate()
            return half_turn_s + self._duration(start, self.depot)
        if self._submerges:
            surface = start.with_alt(self.depot.alt)
            return self._duration(start, surface) + self._duration(surface, self.depot)
        above = self.depot.with_alt(max(start.alt, self.spec.takeoff_alt_m, self.depot.alt))
        return self._duration(start, above) + self._duration(above, self.depot)

    def leg_s(self, a: Position, b: Position) -> float:
        """How long a straight leg in the air from ``a`` to ``b`` takes. The heading at ``a``
        is not known: a ground or surface vehicle's turn before the leg is not counted."""
        return self._duration(a, b)

    def read_sensor(self, read: SensorRead) -> Sample:
        """A simulated vehicle has no sensors of its own: its readings come from the field
        (``fleet.sources``), or from a plug-in on the computer that runs it."""
        raise SensorFailure(f"a simulated vehicle has no {read.source} source", where=read.sensor)

    # Queries

    def position_at(self, t: float) -> Position:
        """Where the vehicle is (or will be, if no other command comes) at time t."""
        i = self._index_at(t)
        if i < 0:
            return self.depot
        return self._steps[i].leg.position_at(t)

    def phase_at(self, t: float) -> str:
        """One of "landed", "takeoff", "cruise", "turning", "landing", "hovering" at time t.

        At the instant one leg ends and the next begins, the next leg's phase is reported.
        """
        i = self._index_at(t)
        if i < 0:
            return PHASE_LANDED
        step = self._steps[i]
        if t < step.leg.end_s:
            return step.leg.phase
        return PHASE_LANDED if step.landed_after else PHASE_HOVERING

    def is_landed_at(self, t: float) -> bool:
        """True when the vehicle sits on the ground at time t (at its depot, unless it was
        told to ``land`` elsewhere)."""
        return self.phase_at(t) == PHASE_LANDED

    def speed_at(self, t: float) -> float:
        """Ground speed at time t in metres a second (0 landed or hovering)."""
        i = self._index_at(t)
        if i < 0:
            return 0.0
        leg = self._steps[i].leg
        if not leg.start_s <= t < leg.end_s:
            return 0.0
        return ground_distance_m(leg.start, leg.end) / (leg.end_s - leg.start_s)

    def planned_legs(self, from_s: float) -> list[Leg]:
        """The legs not yet finished at ``from_s``, in order: the rest of the plan.

        A leg under way at ``from_s`` is returned cut to start at ``from_s`` from the vehicle's
        position then, so the list draws the path still ahead. Empty when hovering or landed.
        """
        legs: list[Leg] = []
        for step in reversed(self._steps):
            leg = step.leg
            if leg.end_s <= from_s:
                break
            if leg.end_s <= leg.start_s:
                continue
            if leg.start_s < from_s:
                leg = Leg(from_s, leg.end_s, leg.position_at(from_s), leg.end, leg.phase)
            legs.append(leg)
        legs.reverse()
        return legs

    def distance_m(self, t: float) -> float:
        """Total 3-D path length flown from creation up to time t, in metres."""
        i = self._index_at(t)
        if i < 0:
            return 0.0
        step = self._steps[i]
        return step.distance_before_m + step.length_m * self._fraction(step.leg, t)

    def flight_s(self, t: float) -> float:
        """Total time spent airborne (moving or hovering) from creation up to time t, in seconds."""
        i = self._index_at(t)
        if i < 0:
            return 0.0
        step = self._steps[i]
        leg = step.leg
        flown = step.flight_before_s + (min(t, leg.end_s) - leg.start_s)
        if not step.landed_after and t > leg.end_s:
            flown += t - leg.end_s
        return flown

    def battery_remaining_s(self, t: float) -> float | None:
        """Endurance left at time t in seconds (never below 0), or None if unlimited.

        Only reported: the simulator does not stop a vehicle whose battery is empty.
        """
        if self.spec.battery_s is None:
            return None
        full_at = 0.0
        for done_s, flown_s in self._charges:
            if done_s <= t:
                full_at = flown_s
        return max(0.0, self.spec.battery_s - (self.flight_s(t) - full_at))

    # Internals

    def _duration(self, start: Position, end: Position) -> float:
        """A straight leg's duration (``fleet.kinematics``): cruise at max speed while climbing
        at the climb rate (descending at the dive rate)."""
        return self.spec.leg_s(start, end)

    def _reachable(self, target: Position) -> Position:
        """``target`` as the vehicle's kind reaches it; ValueError where it cannot go."""
        kind, plane = self.spec.kind, self.depot.alt
        if self._in_plane:
            if abs(target.alt - plane) > _ARRIVAL_SLACK_M:
                raise ValueError(
                    f"a {kind} vehicle moves in the plane at {plane:g} m: it cannot go to "
                    f"altitude {target.alt:g} m"
                )
            return target.with_alt(plane)
        if self._submerges and target.alt > plane + _ARRIVAL_SLACK_M:
            raise ValueError(
                f"an {kind} vehicle goes no higher than the surface ({plane:g} m): it cannot "
                f"go to altitude {target.alt:g} m"
            )
        return target

    def _turn_rate(self) -> float:
        rate = self.spec.turning_rate_dps
        assert rate is not None  # only vehicles that turn in place ask
        return rate

    def _turn_s(self, heading_deg: float, here: Position, target: Position) -> float:
        """Seconds to turn in place from ``heading_deg`` to the leg from ``here`` to
        ``target`` (0 for no horizontal leg)."""
        if here.lat == target.lat and here.lng == target.lng:
            return 0.0
        turn = abs(turn_deg(heading_deg, headings_deg(here, target)[0]))
        return 0.0 if turn < _TURN_SLACK_DEG else turn / self._turn_rate()

    def _turn(self, start_s: float, here: Position, target: Position) -> float:
        """Append the turn in place towards ``target`` (if any); return when it is done."""
        heading = self._heading_at(start_s)
        seconds = self._turn_s(heading, here, target)
        if seconds == 0.0:
            return start_s
        leave = headings_deg(here, target)[0]
        return self._append(
            start_s, here, here, PHASE_TURNING, duration_s=seconds, headings=(heading, leave)
        )

    def _heading_at(self, t: float) -> float:
        """The heading at time t (kept for vehicles that turn in place): turns and legs change
        it evenly from their start to their end."""
        i = self._index_at(t)
        if i < 0:
            return _NORTH_DEG
        step = self._steps[i]
        fraction = self._fraction(step.leg, t)
        start, end = step.heading_from_deg, step.heading_to_deg
        return (start + turn_deg(start, end) * fraction) % 360.0

    def _index_at(self, t: float) -> int:
        """Index of the last step started at or before t, or -1."""
        return bisect_right(self._starts, t) - 1

    @staticmethod
    def _fraction(leg: Leg, t: float) -> float:
        if t >= leg.end_s or leg.end_s <= leg.start_s:
            return 1.0
        return max(0.0, (t - leg.start_s) / (leg.end_s - leg.start_s))

    def _begin_command(self, now_s: float) -> tuple[Position, bool]:
        """Validate the time, drop the plan after ``now_s``; return the position and landed flag."""
        if not math.isfinite(now_s):
            raise ValueError(f"now_s must be a finite number, got {now_s!r}")
        if now_s < self._command_s:
            raise ValueError(
                f"now_s={now_s!r} is earlier than the previous command at {self._command_s!r} s; "
                "commands must come in time order"
            )
        self._truncate(now_s)
        self._command_s = now_s
        return self.position_at(now_s), self.is_landed_at(now_s)

    def _truncate(self, now_s: float) -> None:
        # Legs that had not begun by now_s were never flown: drop them entirely.
        while self._steps and (
            self._starts[-1] > now_s
            or (self._starts[-1] == now_s and self._steps[-1].leg.end_s > now_s)
        ):
            self._steps.pop()
            self._starts.pop()
        if not self._steps:
            return
        step = self._steps[-1]
        leg = step.leg
        if leg.start_s < now_s < leg.end_s:
            fraction = (now_s - leg.start_s) / (leg.end_s - leg.start_s)
            cut = Leg(leg.start_s, now_s, leg.start, leg.position_at(now_s), leg.phase)
            # Scaling the stored length (rather than re-measuring) keeps the odometer continuous.
            self._steps[-1] = _Step(
                leg=cut,
                length_m=step.length_m * fraction,
                landed_after=False,
                distance_before_m=step.distance_before_m,
                flight_before_s=step.flight_before_s,
                heading_from_deg=step.heading_from_deg,
                heading_to_deg=self._heading_at(now_s),
            )

    def _append(
        self,
        start_s: float,
        start: Position,
        end: Position,
        phase: str,
        *,
        landed_after: bool = False,
        duration_s: float | None = None,
        headings: tuple[float, float] | None = None,
    ) -> float:
        """Add one leg starting at start_s; return its end time. ``duration_s``: the leg's
        (a turn's), else the straight leg's; ``headings``: at its start and end, else those
        of the way it goes (kept only for vehicles that turn in place)."""
        end_s = start_s + (self._duration(start, end) if duration_s is None else duration_s)
        if self._steps:
            prev = self._steps[-1]
            hover_s = 0.0 if prev.landed_after else start_s - prev.leg.end_s
            distance_before = prev.distance_before_m + prev.length_m
            flight_before = prev.flight_before_s + prev.leg.duration_s + hover_s
            heading = prev.heading_to_deg
        else:
            distance_before = 0.0
            flight_before = 0.0
            heading = _NORTH_DEG
        if headings is None:
            headings = (heading, heading)
            moves = start.lat != end.lat or start.lng != end.lng
            if moves and self.spec.turning_rate_dps is not None:
                headings = headings_deg(start, end)
        self._steps.append(
            _Step(
                leg=Leg(start_s, end_s, start, end, phase),
                length_m=distance_m(start, end),
                landed_after=landed_after,
                distance_before_m=distance_before,
                flight_before_s=flight_before,
                heading_from_deg=headings[0],
                heading_to_deg=headings[1],
            )
        )
        self._starts.append(start_s)
        return end_s
