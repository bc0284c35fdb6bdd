"""The planners' arena: a fleet serving a stream of point tasks, without the platform around it.

Pure Python (no Django, no V8): simulated vehicles (`fleet.simulation.SimVehicle`), the vehicle
mapper's rules (`mapping.map_task`) and the route planners, on discrete-event time. Each
vehicle follows the control loop of `vvm_worker.executor.VehicleLoop`: it asks its planner
whenever it arrives somewhere or gets work (in flight too when the planner `retargets`), reads
every open task within tolerance of where it stops, and when idle waits at its standby position
(planners that `stands_by`) or flies home. `simulate` runs the same loop with the whole
platform around it (programs, journal, database); for streams of one-task VVs both give the same
latencies (the bench checks it on a few seeds), and this one is a hundred times faster, which is
what a sweep over planners, arrival rates and seeds needs.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from shapely.geometry import Polygon

from fleet.geo import Position, distance_m
from fleet.simulation import SimVehicle
from fleet.simulation import VehicleSpec as Kinematics
from vvm_worker.mapping import VehicleCaps, map_task
from vvm_worker.planning import (
    STANDBY_S,
    Planner,
    PlanTask,
    TravelTime,
    make_planner,
    standby_position,
)
from vvm_worker.runtime.types import TaskRequest

TOLERANCE_M = 4.0
_REACH_SLACK_M = 1e-3
_RECENT = 20  # served tasks whose altitudes place the standby position


@dataclass(frozen=True)
class ArenaVehicle:
    """One RV: its depot, operation area ((lat, lng) ring), limits and speeds."""

    name: str
    depot: Position
    area: Sequence[tuple[float, float]]
    max_speed_mps: float = 10.0
    climb_rate_mps: float = 3.0
    min_altitude_m: float = 0.0
    max_altitude_m: float = 60.0


@dataclass(frozen=True)
class ArenaTask:
    """A point task requested at `at_s`."""

    at_s: float
    position: Position


@dataclass
class ArenaResult:
    """What a run gives: per task its vehicle and completion time; per vehicle its distance
    flown (back at its depot) and tasks served."""

    requested_s: list[float]
    done_s: list[float]
    vehicle: list[str]
    distance_m: dict[str, float]
    served: dict[str, int]
    planning_s: list[float] = field(default_factory=list)

    @property
    def latencies_s(self) -> list[float]:
        return [done - asked for asked, done in zip(self.requested_s, self.done_s, strict=True)]

    @property
    def makespan_s(self) -> float:
        return max(self.done_s, default=0.0)


class _Rig:
    """One vehicle with its planner and the state of its control loop."""

    def __init__(self, spec: ArenaVehicle, planner: Planner) -> None:
        self.spec = spec
        self.planner = planner
        self.driver = SimVehicle(
            Kinematics(max_speed_mps=spec.max_speed_mps, climb_rate_mps=spec.climb_rate_mps),
            spec.depot,
        )
        self.polygon = Polygon([(lng, lat) for lat, lng in spec.area])
        self.open: dict[int, PlanTask] = {}
        self.target: int | None = None
        self.token = 0
        self.recent: list[float] = []
        self.route: list[PlanTask] = []

    def caps(self, now: float, with_route: bool = True) -> VehicleCaps:
        return VehicleCaps(
            id=id(self),
            name=self.spec.name,
            area=self.polygon,
            min_altitude_m=self.spec.min_altitude_m,
            max_altitude_m=self.spec.max_altitude_m,
            sensors=frozenset({"GPS"}),
            active=True,
            position=self.driver.position_at(now),
            max_speed_mps=self.spec.max_speed_mps,
            climb_rate_mps=self.spec.climb_rate_mps,
            open_tasks=len(self.open),
            route=tuple(t.position for t in self.route if t.id in self.open) if with_route else (),
        )


class Arena:
    """Run `tasks` on `vehicles` with the planner `planner` (a name of `PLANNER_NAMES`)."""

    def __init__(
        self,
        vehicles: Sequence[ArenaVehicle],
        tasks: Sequence[ArenaTask],
        planner: str,
        *,
        standby_s: float = STANDBY_S,
        clock: Callable[[], float] | None = None,
        mapper_knows_routes: bool = True,
    ) -> None:
        self.rigs = [
            _Rig(
                v,
                make_planner(planner, travel_time=TravelTime(v.max_speed_mps, v.climb_rate_mps)),
            )
            for v in vehicles
        ]
        self.tasks = list(tasks)
        self.standby_s = standby_s
        self.clock = clock  # wall clock for timing the planners (perf_counter), or None
        # False: the mapper ranks RVs as it once did, by distance plus 30 s per queued task.
        self.mapper_knows_routes = mapper_knows_routes
        self._queue: list[tuple[float, int, Callable[[float], None]]] = []
        self._seq = itertools.count()
        self.done: list[float] = [math.nan] * len(self.tasks)
        self.by: list[str] = [""] * len(self.tasks)
        self.planning_s: list[float] = []

    def run(self) -> ArenaResult:
        for index, task in enumerate(self.tasks):
            self._at(task.at_s, functools.partial(self._request, index))
        while self._queue:
            t, _, fn = heapq.heappop(self._queue)
            fn(t)
        requested = [task.at_s for task in self.tasks]
        if any(math.isnan(done) for done in self.done):
            missing = [i for i, done in enumerate(self.done) if math.isnan(done)]
            raise RuntimeError(f"tasks {missing[:10]} were never served")
        end = max(rig.driver.plan_end_s for rig in self.rigs)
        return ArenaResult(
            requested_s=requested,
            done_s=list(self.done),
            vehicle=list(self.by),
            distance_m={rig.spec.name: rig.driver.distance_m(end) for rig in self.rigs},
            served={rig.spec.name: self.by.count(rig.spec.name) for rig in self.rigs},
            planning_s=self.planning_s,
        )

    def _at(self, t: float, fn: Callable[[float], None]) -> None:
        heapq.heappush(self._queue, (t, next(self._seq), fn))

    # --- the mapper ------------------------------------------------------------------------------

    def _request(self, index: int, now: float) -> None:
        p = self.tasks[index].position
        request = TaskRequest(p.lat, p.lng, p.alt, TOLERANCE_M, ("GPS",))
        caps = [rig.caps(now, self.mapper_knows_routes) for rig in self.rigs]
        decision = map_task(request, caps)
        if decision.rejected or not decision.candidates:
            raise ValueError(f"task {index} at {p}: {decision.reason or 'no vehicle'}")
        rig = next(r for r, c in zip(self.rigs, caps, strict=True) if c is decision.candidates[0])
        rig.open[index] = PlanTask(index, p, self.tasks[index].at_s)
        self._wake(rig, now)

    # --- the control loop (as VehicleLoop) ----------------------------------------------------

    def _wake(self, rig: _Rig, now: float) -> None:
        if rig.target is not None and rig.target in rig.open and not rig.planner.retargets:
            return
        self._plan(rig, now)

    def _plan(self, rig: _Rig, now: float) -> None:
        here = rig.driver.position_at(now)
        tasks = list(rig.open.values())
        start = self.clock() if self.clock is not None else 0.0
        choice = rig.planner.next_task(here, tasks, now) if tasks else None
        rig.route = rig.planner.route(here, tasks, now) if tasks else []
        if self.clock is not None and tasks:
            self.planning_s.append(self.clock() - start)
        if choice is not None and choice.id == rig.target:
            return  # still the best target: fly on
        rig.token += 1
        token = rig.token
        if choice is not None:
            rig.target = choice.id
            arrival = rig.driver.fly_to(choice.position, now)
            self._at(arrival, lambda t: self._arrive(rig, token, t))
            return
        rig.target = None
        if rig.driver.is_landed_at(now):
            return
        if rig.planner.stands_by:
            spot = standby_position(
                rig.polygon,
                rig.recent,
                min_altitude_m=rig.spec.min_altitude_m,
                max_altitude_m=rig.spec.max_altitude_m,
            )
            there = rig.driver.fly_to(spot, now)
            self._at(there + self.standby_s, lambda t: self._home(rig, token, t))
        else:
            rig.driver.return_to_depot(now)

    def _home(self, rig: _Rig, token: int, now: float) -> None:
        if token == rig.token:
            rig.token += 1
            rig.driver.return_to_depot(now)

    def _arrive(self, rig: _Rig, token: int, now: float) -> None:
        if token != rig.token:
            return
        rig.target = None
        here = rig.driver.position_at(now)
        for index, task in sorted(
            rig.open.items(), key=lambda item: (item[1].requested_s, item[0])
        ):
            if distance_m(here, task.position) <= TOLERANCE_M + _REACH_SLACK_M:
                del rig.open[index]
                self.done[index] = now
                self.by[index] = rig.spec.name
                rig.recent = [*rig.recent[-_RECENT + 1 :], task.position.alt]
        self._plan(rig, now)
