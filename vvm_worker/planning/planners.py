"""The four route planners a vehicle can run, and `make_planner` to pick one by name.

- `tour` (the default): re-plans a short open path over all open tasks at every call.
- `nearest`: the paper's nearest neighbour.
- `gated-tsp`: the original CPCC implementation's default, exact tours over batches of at
  most 30 waiting tasks; tasks that arrive during a tour wait for the next one.
- `fcfs`: first come, first served.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from fleet.geo import Position, distance_m

from .base import CostFn, Planner, PlanTask, canonical_order
from .costs import build_cost_matrix, costs_from
from .exact import HELD_KARP_LIMIT, NODE_LIMIT, solve_open_path
from .heuristics import first_cheapest, greedy_chain, improve_path, improve_with_restarts

PLANNER_NAMES: tuple[str, ...] = ("tour", "nearest", "gated-tsp", "fcfs")
DEFAULT_PLANNER = "tour"
GATED_TOUR_LIMIT = 30
"""At most this many waiting tasks (the earliest requested) make up one gated-TSP tour."""


class FcfsPlanner:
    """First come, first served: the earliest requested task, then the lowest id. Stateless."""

    name: str = "fcfs"

    def next_task(self, current: Position, open_tasks: Sequence[PlanTask]) -> PlanTask | None:
        """The earliest requested open task, or None. Raises ValueError on duplicate ids."""
        tasks = canonical_order(open_tasks)
        return tasks[0] if tasks else None

    def route(self, current: Position, open_tasks: Sequence[PlanTask]) -> list[PlanTask]:
        """All open tasks by (requested_s, id). Raises ValueError on duplicate ids."""
        return canonical_order(open_tasks)

    def state(self) -> dict[str, Any]:
        """Always {}: there is nothing to keep."""
        return {}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Accepts and ignores any snapshot (it may come from another planner)."""


class NearestPlanner:
    """The paper's nearest neighbour: the open task cheapest to reach from where the vehicle is.

    Costs within 1e-9 (relative) of the cheapest count as ties, broken by (requested_s, id).
    Stateless. `cost` is called once per open task in `next_task`; `route` builds the whole
    cost matrix (see `build_cost_matrix`).
    """

    name: str = "nearest"

    def __init__(self, cost: CostFn = distance_m) -> None:
        self.cost = cost

    def next_task(self, current: Position, open_tasks: Sequence[PlanTask]) -> PlanTask | None:
        """The nearest open task, or None. Raises ValueError on duplicate ids or bad costs."""
        tasks = canonical_order(open_tasks)
        if not tasks:
            return None
        costs = costs_from(self.cost, current, [task.position for task in tasks])
        return tasks[first_cheapest(costs)]

    def route(self, current: Position, open_tasks: Sequence[PlanTask]) -> list[PlanTask]:
        """The nearest-neighbour chain through all open tasks, starting at `current`."""
        tasks = canonical_order(open_tasks)
        if not tasks:
            return []
        matrix = build_cost_matrix(self.cost, current, [task.position for task in tasks])
        return [tasks[node - 1] for node in greedy_chain(matrix)[1:]]

    def state(self) -> dict[str, Any]:
        """Always {}: there is nothing to keep."""
        return {}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Accepts and ignores any snapshot (it may come from another planner)."""


class TourPlanner:
    """The project's default: at every call, a short open path over all open tasks.

    Up to `exact_limit` tasks the path is optimal (Held-Karp, a few milliseconds). Above, it is
    the nearest-neighbour path improved by 2-opt and Or-opt moves for open paths (with a few
    seeded restarts up to `restart_limit` tasks), restricted to neighbour lists. The path is
    never costlier than the nearest-neighbour path. Stateless: equal inputs give equal paths.

    Measured on a 2-core machine: 1,000 tasks take about 30 ms with the default cost, whose
    matrix is vectorised. A custom cost is called for every ordered pair of tasks, about 1 s at
    1,000 tasks for a cost that calls `distance_m` (0.1 s at 300).

    Because it always minimises the remaining path, a far task can be postponed for as long as
    nearer tasks keep arriving; callers that need a bound on waiting should use `fcfs` or
    `gated-tsp`.
    """

    name: str = "tour"

    def __init__(
        self, cost: CostFn = distance_m, *, exact_limit: int = 9, restart_limit: int = 40
    ) -> None:
        self.cost = cost
        self.exact_limit = exact_limit
        self.restart_limit = restart_limit

    def next_task(self, current: Position, open_tasks: Sequence[PlanTask]) -> PlanTask | None:
        """The first task of `route`, or None. Raises ValueError on duplicate ids or bad costs."""
        planned = self.route(current, open_tasks)
        return planned[0] if planned else None

    def route(self, current: Position, open_tasks: Sequence[PlanTask]) -> list[PlanTask]:
        """All open tasks in the order of the planned open path from `current`."""
        tasks = canonical_order(open_tasks)
        if not tasks:
            return []
        matrix = build_cost_matrix(self.cost, current, [task.position for task in tasks])
        if len(tasks) <= self.exact_limit:
            path = solve_open_path(matrix).path
        elif len(tasks) <= self.restart_limit:
            path = improve_with_restarts(matrix, greedy_chain(matrix), rounds=10)
        else:
            path = improve_path(matrix, greedy_chain(matrix))
        return [tasks[node - 1] for node in path[1:]]

    def state(self) -> dict[str, Any]:
        """Always {}: every call re-plans from scratch."""
        return {}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Accepts and ignores any snapshot (it may come from another planner)."""


class GatedTspPlanner:
    """The original CPCC implementation's default: exact tours over gated batches of tasks.

    With no tour in progress, it takes the `tour_limit` (30) earliest requested open tasks and
    computes the minimum-cost open path through them from the current position (Held-Karp up
    to 13 tasks, branch and bound above; see `exact.solve_open_path`). It then serves that tour
    in order. Tasks that arrive meanwhile wait until the tour is done, however near they are;
    tour tasks that are no longer open are skipped.

    Measured on a 2-core machine with the default cost, per new tour: about 20 ms at 15 tasks
    (Held-Karp), 5-80 ms at 20 and 10-150 ms at 30 tasks (uniform, clustered, grid-shaped and
    duplicate positions, and with an asymmetric climb-costs-more cost). The problem is NP-hard:
    costs without geometry (e.g. a random table) can need seconds at 18 tasks, so the search
    stops after `node_limit` nodes (about 15 s), keeps the best tour found and reports
    `state()["exact"]` False.

    State: the ids of the tour in progress and whether it was proven optimal.
    """

    name: str = "gated-tsp"

    def __init__(
        self,
        cost: CostFn = distance_m,
        *,
        tour_limit: int = GATED_TOUR_LIMIT,
        held_karp_limit: int = HELD_KARP_LIMIT,
        node_limit: int = NODE_LIMIT,
    ) -> None:
        self.cost = cost
        self.tour_limit = tour_limit
        self.held_karp_limit = held_karp_limit
        self.node_limit = node_limit
        self._tour: list[int] = []
        self._exact = True
        # The last tour computed, so that route() followed by next_task() solves it once.
        self._last_plan: tuple[Position, tuple[PlanTask, ...], list[int], bool] | None = None

    def next_task(self, current: Position, open_tasks: Sequence[PlanTask]) -> PlanTask | None:
        """The next task of the tour in progress; starts a new tour when that one is done.

        Returns None when no task is open. Raises ValueError on duplicate ids or bad costs.
        """
        tasks = canonical_order(open_tasks)
        by_id = {task.id: task for task in tasks}
        self._tour = [task_id for task_id in self._tour if task_id in by_id]
        if not self._tour:
            if not tasks:
                self._exact = True
                return None
            self._tour, self._exact = self._plan(current, tasks[: self.tour_limit])
        return by_id[self._tour[0]]

    def route(self, current: Position, open_tasks: Sequence[PlanTask]) -> list[PlanTask]:
        """The tour in progress (or the one `next_task` would start), then the later batches.

        Later batches (the next `tour_limit` earliest waiting tasks, from where the previous
        batch ends) are only a preview ordered by the `tour` heuristic: their exact tour is
        computed when the vehicle gets there, with the tasks open then.
        """
        tasks = canonical_order(open_tasks)
        by_id = {task.id: task for task in tasks}
        tour = [task_id for task_id in self._tour if task_id in by_id]
        if not tour and tasks:
            tour, _ = self._plan(current, tasks[: self.tour_limit])
        planned = [by_id[task_id] for task_id in tour]
        in_tour = set(tour)
        waiting = [task for task in tasks if task.id not in in_tour]
        here = planned[-1].position if planned else current
        preview = TourPlanner(self.cost)
        for start in range(0, len(waiting), self.tour_limit):
            batch = preview.route(here, waiting[start : start + self.tour_limit])
            planned.extend(batch)
            here = batch[-1].position
        return planned

    def state(self) -> dict[str, Any]:
        """{"tour": [task ids still to serve, in order], "exact": proven optimal}."""
        return {"tour": list(self._tour), "exact": self._exact}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Continue the tour of a snapshot; {} (or another planner's snapshot) means no tour.

        Raises ValueError when "tour" is not a list of integer ids or "exact" not a boolean.
        """
        tour = state.get("tour", [])
        exact = state.get("exact", True)
        if not isinstance(tour, list) or not all(
            isinstance(task_id, int) and not isinstance(task_id, bool) for task_id in tour
        ):
            raise ValueError(f"gated-tsp state: 'tour' must be a list of task ids, not {tour!r}")
        if not isinstance(exact, bool):
            raise ValueError(f"gated-tsp state: 'exact' must be true or false, not {exact!r}")
        self._tour = list(tour)
        self._exact = exact

    def _plan(self, current: Position, batch: Sequence[PlanTask]) -> tuple[list[int], bool]:
        key = tuple(batch)
        if self._last_plan is not None and self._last_plan[:2] == (current, key):
            return list(self._last_plan[2]), self._last_plan[3]
        matrix = build_cost_matrix(self.cost, current, [task.position for task in batch])
        result = solve_open_path(
            matrix, held_karp_limit=self.held_karp_limit, node_limit=self.node_limit
        )
        tour = [batch[node - 1].id for node in result.path[1:]]
        self._last_plan = (current, key, tour, result.exact)
        return list(tour), result.exact


def make_planner(name: str, *, cost: CostFn = distance_m) -> Planner:
    """A new planner of the given name (one of `PLANNER_NAMES`) using `cost` between points.

    Raises ValueError naming the unknown name and listing the valid ones.
    """
    if name == "tour":
        return TourPlanner(cost)
    if name == "nearest":
        return NearestPlanner(cost)
    if name == "gated-tsp":
        return GatedTspPlanner(cost)
    if name == "fcfs":
        return FcfsPlanner()
    raise ValueError(f"unknown planner {name!r}; valid planners: {', '.join(PLANNER_NAMES)}")
