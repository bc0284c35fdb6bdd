"""Shared vocabulary of the route planners: tasks, cost functions and the planner protocol.

Pure Python (no Django): the RV worker turns its open tasks into `PlanTask`s, asks a `Planner`
where to fly next and persists `Planner.state()` with the vehicle.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from fleet.geo import Position

CostFn = Callable[[Position, Position], float]
"""Travel cost from the first position to the second (metres, seconds, joules: any unit, but
finite and not negative). It need not be symmetric; the default is `fleet.geo.distance_m`."""


@dataclass(frozen=True, slots=True)
class PlanTask:
    """One open point task as the planner sees it.

    `id` is unique among the open tasks of one vehicle; `requested_s` is when the task was
    requested on the platform clock (seconds) and breaks ties between equally good choices.
    `group` names the request the task belongs to: the tasks of one `executeAll` batch share
    it and the batch is done when its last task is read; None means a request of its own.
    `weight` is how much a second of the request's waiting counts (its customer's service
    class; 1 without one): every planner weighs a request's waiting time by it, and with
    every weight 1 plans as if there were no weights. `deadline_s` is when the task must be
    read by, on the same clock (its request time plus its customer's class's target; None:
    no class, no deadline): see `planning.deadlines`. Raises ValueError when `requested_s` or
    `deadline_s` is not a finite number or `weight` not a positive finite one.
    """

    id: int
    position: Position
    requested_s: float
    group: str | None = None
    weight: float = 1.0
    deadline_s: float | None = None

    def __post_init__(self) -> None:
        if not math.isfinite(self.requested_s):
            raise ValueError(f"task {self.id}: requested_s {self.requested_s!r} is not finite")
        if not (math.isfinite(self.weight) and self.weight > 0):
            raise ValueError(f"task {self.id}: weight {self.weight!r} is not a positive number")
        if self.deadline_s is not None and not math.isfinite(self.deadline_s):
            raise ValueError(f"task {self.id}: deadline_s {self.deadline_s!r} is not finite")


class Planner(Protocol):
    """Decides the order in which one vehicle serves its open tasks.

    The vehicle calls `next_task` whenever it arrives somewhere or gets new work, flies to the
    task returned, serves it and asks again. All planners are deterministic: equal inputs (and
    equal state) give equal answers, and ties are broken by (requested_s, id). `now_s` is the
    platform clock's time of the call (planners that weigh a task's age need it; None: the
    latest request time).

    `retargets`: the vehicle asks again when new work arrives in flight and may turn to another
    task (otherwise it keeps its target until it gets there). `stands_by`: an idle vehicle
    waits in the air where the next task is expected soonest (see `standby_position`) for a
    while before it flies home (otherwise it flies home at once).
    """

    name: str
    retargets: bool
    stands_by: bool

    def next_task(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> PlanTask | None:
        """The task to fly to now, or None when `open_tasks` is empty.

        May update the planner's state (for example start a new tour). Raises ValueError on
        duplicate task ids or when the cost function returns a negative or non-finite value.
        """
        ...

    def route(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """Every open task in the order the planner intends to serve them now ([] when none).

        The first element is what `next_task` would return for the same arguments; calling
        `route` never changes the planner's state. Same errors as `next_task`.
        """
        ...

    def plan(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """`next_task` and `route` in one computation: every open task in the order the
        planner intends to serve them, the first being what `next_task` returns (with the
        same change of state). The vehicle's control loop calls this, once per decision."""
        ...

    def state(self) -> dict[str, Any]:
        """A JSON-serialisable snapshot that `restore` accepts ({} for stateless planners)."""
        ...

    def restore(self, state: Mapping[str, Any]) -> None:
        """Continue from a snapshot taken by `state()`, possibly in another process.

        Tasks the snapshot mentions that are no longer open are ignored when planning.
        Raises ValueError when the snapshot is malformed.
        """
        ...


def canonical_order(open_tasks: Sequence[PlanTask]) -> list[PlanTask]:
    """The tasks sorted by (requested_s, id), the order every tie is broken in.

    Planners work on this order so that their answer does not depend on the order the caller
    happened to list the tasks in. Raises ValueError when two tasks share an id.
    """
    ordered = sorted(open_tasks, key=lambda task: (task.requested_s, task.id))
    if len({task.id for task in ordered}) != len(ordered):
        counts = Counter(task.id for task in ordered)
        duplicates = sorted(task_id for task_id, count in counts.items() if count > 1)
        raise ValueError(f"task ids {duplicates} appear more than once in open_tasks")
    return ordered


def tie_tolerance(value: float) -> float:
    """How close two costs must be to `value` to count as equal (then the order decides).

    Geodesic distances of mirror-image points differ in the last bits; without a tolerance
    such near-ties would be broken by rounding noise instead of by (requested_s, id).
    """
    return 1e-9 * abs(value) + 1e-12


def weighted(open_tasks: Sequence[PlanTask]) -> bool:
    """Whether any task weighs other than 1 (otherwise the planners plan as without weights)."""
    return any(task.weight != 1.0 for task in open_tasks)


def waiting_order(open_tasks: Sequence[PlanTask], now_s: float | None) -> list[PlanTask]:
    """The tasks by weighted waiting, longest first: weight times age at `now_s` (None: the
    latest request time), ties by (requested_s, id). With every weight 1 this is
    `canonical_order` (the oldest first). Raises ValueError when two tasks share an id."""
    ordered = canonical_order(open_tasks)
    if not weighted(ordered):
        return ordered
    now = max(task.requested_s for task in ordered) if now_s is None else now_s
    return sorted(ordered, key=lambda task: -task.weight * max(0.0, now - task.requested_s))
