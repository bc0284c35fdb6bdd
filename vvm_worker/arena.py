"""The planners' arena: a fleet serving a stream of point tasks, without the platform around it.

Pure Python (no Django, no V8): simulated vehicles (`fleet.simulation.SimVehicle`), the vehicle
mapper's rules (`mapping.map_task`) and the route planners, on discrete-event time. Each
vehicle runs the platform's control loop (`vvm_worker.control.ControlLoop`) over a store in
memory: it asks its planner whenever it arrives somewhere or gets work (in flight too when the
planner `retargets`), serves every open task within tolerance of where it stops, and when idle
waits at its standby position (planners that `stands_by`) or flies home. `simulate` runs the
same loop with the whole platform around it (programs, journal, database); for streams of
one-task VVs both give the same
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
from typing import Any

from shapely.geometry import Polygon

from fleet.geo import Position
from fleet.simulation import SimVehicle
from fleet.simulation import VehicleSpec as Kinematics
from vvm_worker.control import (
    ACTIVE,
    Area,
    ControlLoop,
    LoopConfig,
    LoopTask,
    OperatorCommand,
    VehicleState,
)
from vvm_worker.mapping import VehicleCaps, map_task
from vvm_worker.planning import STANDBY_S, Planner, TravelTime, make_planner
from vvm_worker.runtime.types import TaskRequest

TOLERANCE_M = 4.0


@dataclass(frozen=True)
class ArenaVehicle:
    """One RV: its depot, operation area ((lat, lng) ring), limits, speeds and kind
    (`fleet.simulation.VehicleSpec` says what `kind`, `dive_rate_mps`, `turn_rate_dps` do)."""

    name: str
    depot: Position
    area: Sequence[tuple[float, float]]
    max_speed_mps: float = 10.0
    climb_rate_mps: float = 3.0
    min_altitude_m: float = 0.0
    max_altitude_m: float = 60.0
    kind: str = "aerial"
    dive_rate_mps: float | None = None
    turn_rate_dps: float | None = None


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


class MemoryStore:
    """An RV's work in memory (``vvm_worker.control.Store``): the open tasks the mapper gave
    it, always in service; a completed task is recorded in the arena's results."""

    def __init__(self, arena: Arena, spec: ArenaVehicle, polygon: Polygon) -> None:
        self.arena = arena
        self.spec = spec
        self._area = Area(polygon, spec.min_altitude_m, spec.max_altitude_m)
        self.open: dict[int, LoopTask] = {}

    def open_tasks(self) -> Sequence[LoopTask]:
        return sorted(self.open.values(), key=lambda t: (t.requested_s, t.id))

    def status(self) -> str:
        return ACTIVE

    def set_status(self, status: str, *, expected: str | None = None, reason: str = "") -> None:
        raise RuntimeError("the arena's vehicles have no battery and never leave service")

    def take_command(self) -> OperatorCommand | None:
        return None  # no operator in the arena

    def complete(self, task: LoopTask, readings: list[dict[str, Any]], now_s: float) -> None:
        del self.open[task.id]
        self.arena.done[task.id] = now_s
        self.arena.by[task.id] = self.spec.name

    def fail(self, task: LoopTask, reason: str, now_s: float) -> None:
        self.complete(task, [], now_s)  # the arena's vehicles read no sensors

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        pass

    def area(self) -> Area:
        return self._area

    def aboard(self) -> list[dict[str, Any]]:
        return []


class _Rig:
    """One vehicle with its planner, its store and its control loop."""

    def __init__(self, arena: Arena, spec: ArenaVehicle, planner: Planner) -> None:
        self.spec = spec
        self.driver = SimVehicle(
            Kinematics(
                max_speed_mps=spec.max_speed_mps,
                climb_rate_mps=spec.climb_rate_mps,
                kind=spec.kind,
                dive_rate_mps=spec.dive_rate_mps,
                turn_rate_dps=spec.turn_rate_dps,
            ),
            spec.depot,
        )
        self.polygon = Polygon([(lng, lat) for lat, lng in spec.area])
        self.store = MemoryStore(arena, spec, self.polygon)
        self.loop = ControlLoop(
            name=spec.name,
            driver=self.driver,
            planner=planner,
            store=self.store,
            scheduler=arena,
            clock=arena.now_s,
            config=LoopConfig(standby_s=arena.standby_s),
            plan_timer=arena.clock,
        )

    def caps(self, now: float, with_route: bool = True) -> VehicleCaps:
        open_tasks = self.store.open
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
            kind=self.spec.kind,
            dive_rate_mps=self.spec.dive_rate_mps,
            open_tasks=len(open_tasks),
            route=(
                tuple(t.position for t in self.loop.route if t.id in open_tasks)
                if with_route
                else ()
            ),
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
        self.tasks = list(tasks)
        self.standby_s = standby_s
        self.clock = clock  # wall clock for timing the planners (perf_counter), or None
        # False: the mapper ranks RVs as it once did, by distance plus 30 s per queued task.
        self.mapper_knows_routes = mapper_knows_routes
        self._queue: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._now = 0.0
        self.done: list[float] = [math.nan] * len(self.tasks)
        self.by: list[str] = [""] * len(self.tasks)
        self.rigs = [
            _Rig(
                self,
                v,
                make_planner(
                    planner,
                    travel_time=TravelTime(v.max_speed_mps, v.climb_rate_mps, v.dive_rate_mps),
                ),
            )
            for v in vehicles
        ]

    def run(self) -> ArenaResult:
        for index, task in enumerate(self.tasks):
            self.call_at(task.at_s, functools.partial(self._request, index))
        while self._queue:
            self._now, _, fn = heapq.heappop(self._queue)
            fn()
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
            planning_s=[s for rig in self.rigs for s in rig.loop.planning_s],
        )

    # --- the scheduler and the clock of the control loops -------------------------------------

    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self._queue, (t_s, next(self._seq), fn))

    def now_s(self) -> float:
        return self._now

    # --- the mapper ------------------------------------------------------------------------------

    def _request(self, index: int) -> None:
        now = self._now
        p = self.tasks[index].position
        request = TaskRequest(p.lat, p.lng, p.alt, TOLERANCE_M, ("GPS",))
        caps = [rig.caps(now, self.mapper_knows_routes) for rig in self.rigs]
        decision = map_task(request, caps)
        if decision.rejected or not decision.candidates:
            raise ValueError(f"task {index} at {p}: {decision.reason or 'no vehicle'}")
        rig = next(r for r, c in zip(self.rigs, caps, strict=True) if c is decision.candidates[0])
        rig.store.open[index] = LoopTask(index, p, TOLERANCE_M, self.tasks[index].at_s)
        rig.loop.wake()
