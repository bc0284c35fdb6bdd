"""The vehicle mapper's rules: which RVs may serve a point task, and which serves it best.

Pure Python (no Django): the services build `VehicleCaps` from the database.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from shapely.geometry import Point, Polygon

from fleet.geo import Position, distance_m
from vvm_worker.runtime.types import TaskRequest

# Cost of one task already queued on a vehicle, in seconds of flight, when ranking vehicles.
QUEUE_PENALTY_S = 30.0


@dataclass(frozen=True)
class VehicleCaps:
    """What the mapper needs to know about one RV."""

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

    def covers(self, task: TaskRequest) -> bool:
        return bool(self.area.covers(Point(task.lng, task.lat)))

    def can_serve(self, task: TaskRequest) -> bool:
        return (
            self.covers(task)
            and self.min_altitude_m <= task.alt <= self.max_altitude_m
            and set(task.sensors) <= self.sensors
        )

    def cost_s(self, task: TaskRequest) -> float:
        target = Position(task.lat, task.lng, task.alt)
        return (
            distance_m(self.position, target) / self.max_speed_mps
            + QUEUE_PENALTY_S * self.open_tasks
        )


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


def map_task(task: TaskRequest, fleet: Sequence[VehicleCaps]) -> MapDecision:
    """Which RVs can serve the task, ranked by estimated time to get there (then name)."""
    able = [v for v in fleet if v.can_serve(task)]
    active = sorted((v for v in able if v.active), key=lambda v: (v.cost_s(task), v.name))
    if active:
        return MapDecision(tuple(active), parked=False, reason=None)
    if able:
        return MapDecision((), parked=True, reason=None)
    return MapDecision((), parked=False, reason=_why_not(task, fleet))


def _why_not(task: TaskRequest, fleet: Sequence[VehicleCaps]) -> str:
    where = _fmt(task)
    covering = [v for v in fleet if v.covers(task)]
    if not covering:
        return f"no vehicle can serve the task at {where}: it is outside every operation area"
    in_range = [v for v in covering if v.min_altitude_m <= task.alt <= v.max_altitude_m]
    if not in_range:
        lo = min(v.min_altitude_m for v in covering)
        hi = max(v.max_altitude_m for v in covering)
        return (
            f"no vehicle can serve the task at {where}: the altitude is outside what the "
            f"vehicles there can fly ({lo:g} to {hi:g} m)"
        )
    carried = frozenset().union(*(v.sensors for v in in_range))
    missing = sorted(set(task.sensors) - carried)
    if not missing:
        wanted = ", ".join(repr(s) for s in task.sensors)
        return f"no vehicle can serve the task at {where}: none there carries all of {wanted}"
    return f"no vehicle can serve the task at {where}: none there carries " + ", ".join(
        repr(s) for s in missing
    )
