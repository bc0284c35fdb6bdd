"""What one class's requests would get if the fleet served nobody else: a replay of the class's
requests alone (when each reached the fleet, where, its weight and deadline) on the RVs that
served in the period. Each request goes where the mapper would send it (among the RVs that
cover its point, one that reaches it in time, then the one it costs least: the cheapest place
in the RV's planned order, `best_insertion`); each RV plans the way it plans (`Planner.plan`,
then `by_deadline`), flies at its own leg times from its depot, and each reading costs the
time a reading took that RV in the period (`reading_overhead`).

It is an estimate, said plainly: an RV here decides when it arrives (it does not turn mid-leg,
which alone it would rarely need); with nothing to do it stands by and then flies home as a
real one does. The service-level report shows it beside what the class
got, so staff see whether a target can be kept at all: a class whose requests alone come back
later than its target needs more vehicles, not a better order. `make bench-service-levels`
holds it against runs of the class really alone (docs/benchmarks.md).

Pure Python (no Django).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import pairwise

from fleet.geo import Position, interpolate
from fleet.kinematics import take_off_top

from .base import Planner, PlanTask
from .deadlines import by_deadline
from .repairman import best_insertion
from .standby import STANDBY_S

LegTime = Callable[[Position, Position], float]


@dataclass(frozen=True)
class AloneRequest:
    """A request of the class as it was read: ``ready_s`` is when it reached the fleet (its
    request time plus what it took to put it on an RV's list, the same alone); ``read_by``
    the RV that read it (where it goes when no RV of the replay covers its point)."""

    id: int
    position: Position
    requested_s: float
    ready_s: float
    read_by: int
    weight: float = 1.0
    deadline_s: float | None = None

    def plan_task(self) -> PlanTask:
        return PlanTask(
            self.id,
            self.position,
            self.requested_s,
            weight=self.weight,
            deadline_s=self.deadline_s,
        )


@dataclass(frozen=True)
class AloneVehicle:
    """An RV of the replay: where it starts (its depot), its leg times, how to make a planner
    of its kind (a fresh one each replay), what a reading costs it, which points it may serve, and where it waits when it has
    nothing to do (``standby``, for ``standby_s`` before it flies home; None: where it is).
    It starts on the ground at its depot and lands there when it comes home."""

    id: int
    start: Position
    leg: LegTime
    new_planner: Callable[[], Planner]
    overhead_s: float = 0.0
    covers: Callable[[Position], bool] = lambda _: True
    standby: Position | None = None
    standby_s: float = STANDBY_S
    takeoff_alt_m: float | None = None

    def first_leg_s(self, here: Position, target: Position, *, grounded: bool) -> float:
        """Seconds from ``here`` to ``target``; from the ground an aerial RV (one with a
        ``takeoff_alt_m``) first climbs straight up to the target's altitude (at least the
        take-off altitude), as the simulator and the autopilots fly it."""
        if not grounded or self.takeoff_alt_m is None:
            return self.leg(here, target)
        top = take_off_top(here, target, takeoff_alt_m=self.takeoff_alt_m)
        return self.leg(here, top) + self.leg(top, target)


@dataclass(frozen=True)
class Reading:
    """A task a vehicle read: where, when requested and when read (for `reading_overhead`)."""

    position: Position
    requested_s: float
    done_s: float


def reading_overhead(readings: Sequence[Reading], *, leg: LegTime) -> float:
    """What a reading costs a vehicle beyond flying to it, measured: over consecutive readings
    where the second was requested before the first was read (the vehicle went straight from
    one to the other), the median of the time between them minus the leg between them (0 when
    it never did)."""
    ordered = sorted(readings, key=lambda r: r.done_s)
    gaps = sorted(
        max(0.0, b.done_s - a.done_s - leg(a.position, b.position))
        for a, b in pairwise(ordered)
        if b.requested_s <= a.done_s
    )
    return gaps[len(gaps) // 2] if gaps else 0.0


def alone_latencies(
    requests: Sequence[AloneRequest], vehicles: Sequence[AloneVehicle]
) -> dict[int, float]:
    """Each request's latency (reading time minus request time, seconds) when ``vehicles``
    serve these requests and no others (see the module). Raises ValueError when a request
    was read by an RV not among them and none of them covers it."""
    rvs = {v.id: _Rv(v) for v in vehicles}
    latencies: dict[int, float] = {}
    for request in sorted(requests, key=lambda r: (r.ready_s, r.id)):
        now = request.ready_s
        for rv in rvs.values():
            rv.serve_until(now, latencies)
        able = [rv for rv in rvs.values() if rv.vehicle.covers(request.position)]
        if not able:
            if request.read_by not in rvs:
                raise ValueError(f"request {request.id}: read by RV {request.read_by}, not given")
            able = [rvs[request.read_by]]
        best = min(able, key=lambda rv: (*rv.rank(request, now), rv.vehicle.id))
        best.take(request, now)
    for rv in rvs.values():
        rv.serve_until(math.inf, latencies)
    return latencies


class _Rv:
    """An RV during the replay: where it is (or flies to) and when it is free there, its open
    requests in the order it last planned them."""

    def __init__(self, vehicle: AloneVehicle) -> None:
        self.vehicle = vehicle
        self.planner = vehicle.new_planner()
        self.here = vehicle.start
        self.grounded = True
        self.free_s = -math.inf
        self.open: dict[int, AloneRequest] = {}
        self.order: list[int] = []

    def rank(self, request: AloneRequest, now: float) -> tuple[bool, float]:
        """As the mapper ranks it for ``request`` at ``now``: late, then what the request
        costs the customers there (the rest of the leg it flies counts in both)."""
        busy = max(0.0, self.free_s - now)
        route = [self.open[k].position for k in self.order]
        here = self.here if self.open else self.idle_at(now)
        cost, wait = best_insertion(self.vehicle.leg, here, route, request.position)
        late = request.deadline_s is not None and now + busy + wait > request.deadline_s
        return late, busy + cost

    def take(self, request: AloneRequest, now: float) -> None:
        if not self.open:
            self.idle_until(now)
        self.open[request.id] = request
        self.order.append(request.id)

    def idle_at(self, now: float) -> Position:
        """Where the RV, idle since ``free_s`` (at ``here``), is at ``now``: it flies to its
        standby spot, waits there, then flies home."""
        vehicle = self.vehicle
        if vehicle.standby is None or self.free_s >= now or self.free_s == -math.inf:
            return self.here
        at_spot_s = self.free_s + vehicle.leg(self.here, vehicle.standby)
        return _along(self.here, self.free_s, vehicle.standby, at_spot_s, vehicle, now)

    def idle_until(self, now: float) -> None:
        """The RV, idle, gets work at ``now``: it is where ``idle_at`` says (on the ground if
        that is home)."""
        if self.free_s >= now:
            return
        self.here = self.idle_at(now)
        self.grounded = self.grounded or self.here == self.vehicle.start
        self.free_s = now

    def serve_until(self, now: float, latencies: dict[int, float]) -> None:
        """Every decision it takes before ``now`` (one at ``now`` waits for the requests that
        reach the fleet then): plan, fly to the first, read it."""
        vehicle = self.vehicle
        while self.open and self.free_s < now:
            tasks = [r.plan_task() for r in self.open.values()]
            plan = self.planner.plan(self.here, tasks, self.free_s)
            order = by_deadline(plan, start=self.here, now_s=self.free_s, leg=vehicle.leg)
            chosen = self.open.pop(order[0].id)
            self.order = [t.id for t in order[1:]]
            flight_s = vehicle.first_leg_s(self.here, chosen.position, grounded=self.grounded)
            self.free_s += flight_s + vehicle.overhead_s
            self.here, self.grounded = chosen.position, False
            latencies[chosen.id] = self.free_s - chosen.requested_s


def _along(
    start: Position,
    left_s: float,
    spot: Position,
    at_spot_s: float,
    vehicle: AloneVehicle,
    now: float,
) -> Position:
    """Where an RV is at ``now`` that left ``start`` at ``left_s`` for ``spot`` (there at
    ``at_spot_s``), waits there ``vehicle.standby_s``, then flies home."""
    if now < at_spot_s:
        return interpolate(start, spot, (now - left_s) / (at_spot_s - left_s))
    leaves_s = at_spot_s + vehicle.standby_s
    home_s = vehicle.leg(spot, vehicle.start)
    if now < leaves_s:
        return spot
    if now < leaves_s + home_s:
        return interpolate(spot, vehicle.start, (now - leaves_s) / home_s)
    return vehicle.start
