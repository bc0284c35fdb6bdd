"""The vehicle mapper's rules: which RVs may serve a point task, and which serves it best.

Pure Python (no Django): the services build `VehicleCaps` from the database.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from shapely.geometry import Point, Polygon

from fleet.airspace import ExclusionZone
from fleet.geo import Position
from fleet.kinds import AERIAL, DEFAULT_KIND, UNDERWATER
from vvm_worker.planning import TravelTime, best_insertion
from vvm_worker.runtime.types import TaskRequest

__all__ = [
    "QUEUE_PENALTY_S",
    "ExclusionZone",
    "MapDecision",
    "Reserve",
    "VehicleCaps",
    "map_task",
]

# Cost of one task queued on a vehicle whose route the mapper does not know, in seconds.
QUEUE_PENALTY_S = 30.0


@dataclass(frozen=True)
class VehicleCaps:
    """What the mapper needs to know about one RV. Its altitude band (metres above home; below
    0 is depth) already keeps within its kind's limits (`fleet.kinds`): a task at 0 m suits
    an aerial, ground or surface vehicle, one below 0 only an underwater one."""

    id: int
    name: str
    area: Polygon  # (lng, lat) coordinates
    min_altitude_m: float
    max_altitude_m: float
    sensors: frozenset[str]
    active: bool  # in service now (not in maintenance)
    position: Position
    max_speed_mps: float
    open_tasks: int = 0
    climb_rate_mps: float = 3.0
    # The open tasks aboard in the order the RV's planner means to serve them (all or some).
    route: tuple[Position, ...] = ()
    # The provider's no-fly zones, the same for every RV.
    no_fly: tuple[ExclusionZone, ...] = ()
    kind: str = DEFAULT_KIND
    dive_rate_mps: float | None = None  # how fast it goes down (None: its climb rate)
    # The service class of each of its open tasks the mapper knows (None: no class).
    task_classes: tuple[int | None, ...] = ()

    def covers(self, task: TaskRequest) -> bool:
        return bool(self.area.covers(Point(task.lng, task.lat)))

    def can_serve(self, task: TaskRequest) -> bool:
        return (
            self.covers(task)
            and self.min_altitude_m <= task.alt <= self.max_altitude_m
            and set(task.sensors) <= self.sensors
            and not any(zone.holds(task) for zone in self.no_fly)
        )

    def travel(self) -> TravelTime:
        return TravelTime(self.max_speed_mps, self.climb_rate_mps, dive_rate_mps=self.dive_rate_mps)

    def cost_s(self, task: TaskRequest) -> float:
        """What giving the task to this RV costs the customers, in seconds: the task's own wait
        plus the delay it causes the tasks already on the RV's route, where the planner would
        fit it in (`planning.insertion_cost` with the RV's travel times)."""
        return self.insertion(task)[0]

    def rank(self, task: TaskRequest, due_in_s: float | None) -> tuple[bool, float]:
        """How the mapper ranks this RV for the task (lower first): late, then ``cost_s``.
        Late: it would reach the task after ``due_in_s`` (None: no deadline, never late), at
        the place where the planner would fit it in."""
        cost, wait = self.insertion(task)
        return due_in_s is not None and wait > due_in_s, cost

    def insertion(self, task: TaskRequest) -> tuple[float, float]:
        """(``cost_s``, when the RV would reach the task there), in seconds; its tasks the
        mapper does not know count ``QUEUE_PENALTY_S`` each in both."""
        target = Position(task.lat, task.lng, task.alt)
        unknown = QUEUE_PENALTY_S * max(0, self.open_tasks - len(self.route))
        cost, wait = best_insertion(self.travel(), self.position, self.route, target)
        return cost + unknown, wait + unknown


@dataclass(frozen=True)
class Reserve:
    """The service classes that give way now (``classes``; None stands for the customers
    without a class): while another class without slack is being served, their tasks leave a
    reserve of RVs to it, so that its next request finds an RV that is free or serving it,
    standing by in the middle of the area, instead of every RV out at a flood's far tasks.

    The reserve for a task is half of the active RVs that can serve it (rounded down: none
    where one can), those that hold the fewest tasks of the classes giving way (then by
    name). A task of such a class goes to another RV, and to a reserve RV only where every
    other would be late for it (its own class's deadline): giving way never makes a class
    miss its own target. ``services.service_levels.classes_giving_way`` says who gives way."""

    classes: frozenset[int | None]

    def gives_way(self, service_class: int | None) -> bool:
        return service_class in self.classes

    def held(self, vehicle: VehicleCaps) -> int:
        """How many tasks of the classes giving way the RV holds."""
        return sum(1 for c in vehicle.task_classes if c in self.classes)

    def kept(self, able: Sequence[VehicleCaps]) -> frozenset[int]:
        """The ids of the RVs of ``able`` (the active RVs that can serve a task) kept free."""
        ordered = sorted(able, key=lambda v: (self.held(v), v.name))
        return frozenset(v.id for v in ordered[: len(able) // 2])


NO_RESERVE = Reserve(frozenset())


@dataclass(frozen=True)
class MapDecision:
    """The mapper's answer for one task.

    ``candidates``: active RVs that can serve it, best first. ``parked``: none is active, but an
    RV in maintenance could serve it, so the VV waits. ``reason``: nobody can, and why.
    """

    candidates: tuple[VehicleCaps, ...]
    parked: bool
    reason: str | None

    @property
    def rejected(self) -> bool:
        return self.reason is not None


def _fmt(task: TaskRequest) -> str:
    return f"({task.lat:.6f}, {task.lng:.6f}) at {task.alt:g} m"


def map_task(
    task: TaskRequest,
    fleet: Sequence[VehicleCaps],
    *,
    due_in_s: float | None = None,
    service_class: int | None = None,
    reserve: Reserve = NO_RESERVE,
) -> MapDecision:
    """Which RVs can serve the task, ranked by what it costs the customers to give it to them
    (`VehicleCaps.cost_s`, then name): where areas overlap, the RV that serves it soonest
    without holding up its other tasks more than another would. ``due_in_s``: the task's
    deadline from now (its customer's class's target; None: none): the RVs that can reach it
    in time come first. A task of a class giving way (``service_class`` in ``reserve``) puts
    the reserve's RVs after the others that reach it in time."""
    able = [v for v in fleet if v.can_serve(task)]
    active = [v for v in able if v.active]
    ranks = {v.id: v.rank(task, due_in_s) for v in active}
    kept = reserve.kept(active) if reserve.gives_way(service_class) else frozenset()
    active.sort(key=lambda v: (ranks[v.id][0], v.id in kept, ranks[v.id][1], v.name))
    if active:
        return MapDecision(tuple(active), parked=False, reason=None)
    if able:
        return MapDecision((), parked=True, reason=None)
    return MapDecision((), parked=False, reason=_why_not(task, fleet))


def _why_not(task: TaskRequest, fleet: Sequence[VehicleCaps]) -> str:
    where = _fmt(task)
    if fleet and any(zone.holds(task) for zone in fleet[0].no_fly):
        return f"no vehicle can serve the task at {where}: it is inside a no-fly zone"
    covering = [v for v in fleet if v.covers(task)]
    if not covering:
        return f"no vehicle can serve the task at {where}: it is outside every operation area"
    in_range = [v for v in covering if v.min_altitude_m <= task.alt <= v.max_altitude_m]
    if not in_range:
        return f"no vehicle can serve the task at {where}: " + _out_of_reach(task, covering)
    carried = frozenset().union(*(v.sensors for v in in_range))
    missing = sorted(set(task.sensors) - carried)
    if not missing:
        wanted = ", ".join(repr(s) for s in task.sensors)
        return f"no vehicle can serve the task at {where}: none there carries all of {wanted}"
    return f"no vehicle can serve the task at {where}: none there carries " + ", ".join(
        repr(s) for s in missing
    )


def _out_of_reach(task: TaskRequest, covering: Sequence[VehicleCaps]) -> str:
    """Why no vehicle whose area covers the task reaches its altitude, in the customer's
    words: how deep or high it is and what kind of vehicle would be needed, naming none."""
    if task.alt < 0:
        subs = [v for v in covering if v.kind == UNDERWATER]
        depth = f"the task is {-task.alt:g} m below the surface"
        if not subs:
            return f"{depth}: no underwater vehicle covers it"
        deepest = min(v.min_altitude_m for v in subs)
        return f"{depth}: the underwater vehicles there dive to {-deepest:g} m at most"
    flying = [v for v in covering if v.kind == AERIAL] if task.alt > 0 else covering
    if not flying:
        return f"the task is {task.alt:g} m above the ground: no aerial vehicle covers it"
    lo = min(v.min_altitude_m for v in flying)
    hi = max(v.max_altitude_m for v in flying)
    return f"the altitude is outside what the vehicles there can fly ({lo:g} to {hi:g} m)"
