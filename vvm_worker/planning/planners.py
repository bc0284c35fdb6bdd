"""The route planners a vehicle can run, and `make_planner` to pick one by name.

Every planner weighs a request's waiting by its `PlanTask.weight` (the customer's service
class), each the way its objective allows (see each class); with every weight 1 each plans
exactly as without weights.

- `latency` (the default): least total waiting of the customers (traveling repairman), with
  old tasks weighing more; shortest tours for batches and surveys; re-planned as tasks arrive.
- `tour`: re-plans a short open path over all open tasks at every call.
- `nearest`: the paper's nearest neighbour.
- `gated-tsp`: the original CPCC implementation's default, exact tours over batches of at
  most 30 waiting tasks; tasks that arrive during a tour wait for the next one.
- `fcfs`: first come, first served.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fleet.airspace import Airspace
from fleet.geo import Position, distance_m

from .base import CostFn, Planner, PlanTask, canonical_order, waiting_order, weighted
from .costs import AroundZones, TaskCosts, TravelTime, build_cost_matrix, costs_from
from .exact import HELD_KARP_LIMIT, NODE_LIMIT, solve_open_path
from .heuristics import (
    first_cheapest,
    greedy_chain,
    improve_path,
    improve_with_restarts,
    iterated_local_search,
)
from .repairman import RepairmanSearch, exact_path, greedy_path

PLANNER_NAMES: tuple[str, ...] = ("latency", "tour", "nearest", "gated-tsp", "fcfs")
DEFAULT_PLANNER = "latency"
GATED_TOUR_LIMIT = 30
"""At most this many waiting tasks (the earliest requested) make up one gated-TSP tour."""


class FcfsPlanner:
    """First come, first served: the earliest requested task, then the lowest id. Weighted:
    the longest weighted waiting first (weight times age at `now_s`, see `waiting_order`), so
    a request of weight 4 overtakes one of weight 1 that has waited up to 4 times as long.
    Stateless."""

    name: str = "fcfs"
    retargets: bool = False
    stands_by: bool = False

    def next_task(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> PlanTask | None:
        """The earliest requested open task, or None. Raises ValueError on duplicate ids."""
        tasks = waiting_order(open_tasks, now_s)
        return tasks[0] if tasks else None

    def route(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """All open tasks by (requested_s, id), or by weighted waiting when weighted. Raises
        ValueError on duplicate ids."""
        return waiting_order(open_tasks, now_s)

    def plan(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """`route`: the first task is `next_task`'s (there is no state to change)."""
        return self.route(current, open_tasks, now_s)

    def state(self) -> dict[str, Any]:
        """Always {}: there is nothing to keep."""
        return {}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Accepts and ignores any snapshot (it may come from another planner)."""


class NearestPlanner:
    """The paper's nearest neighbour: the open task cheapest to reach from where the vehicle is.

    Costs within 1e-9 (relative) of the cheapest count as ties, broken by (requested_s, id).
    Weighted: the least cost per unit of weight (a request of weight 4 four times as far away
    ties with one of weight 1). Stateless. `cost` is called once per open task in `next_task`; `route` builds the whole
    cost matrix (see `build_cost_matrix`).
    """

    name: str = "nearest"
    retargets: bool = False
    stands_by: bool = False

    def __init__(self, cost: CostFn = distance_m) -> None:
        self.cost = cost

    def next_task(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> PlanTask | None:
        """The nearest open task, or None. Raises ValueError on duplicate ids or bad costs."""
        tasks = canonical_order(open_tasks)
        if not tasks:
            return None
        costs = costs_from(self.cost, current, [task.position for task in tasks])
        if weighted(tasks):
            costs = costs / np.asarray([task.weight for task in tasks])
        return tasks[first_cheapest(costs)]

    def route(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """The nearest-neighbour chain through all open tasks, starting at `current`."""
        tasks = canonical_order(open_tasks)
        if not tasks:
            return []
        matrix = build_cost_matrix(self.cost, current, [task.position for task in tasks])
        weights = node_weights(tasks) if weighted(tasks) else None
        return [tasks[node - 1] for node in greedy_chain(matrix, weights)[1:]]

    def plan(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """`route`: the first task is `next_task`'s (there is no state to change)."""
        return self.route(current, open_tasks, now_s)

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

    Weighted: a path has no waiting to weigh, so the weights rank: the heaviest requests
    first (their shortest path), then from its end the next weight's, and so on.
    """

    name: str = "tour"
    retargets: bool = False
    stands_by: bool = False

    def __init__(
        self, cost: CostFn = distance_m, *, exact_limit: int = 9, restart_limit: int = 40
    ) -> None:
        self.cost = cost
        self.exact_limit = exact_limit
        self.restart_limit = restart_limit

    def next_task(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> PlanTask | None:
        """The first task of `route`, or None. Raises ValueError on duplicate ids or bad costs."""
        planned = self.route(current, open_tasks)
        return planned[0] if planned else None

    def route(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """All open tasks in the order of the planned open path from `current`."""
        tasks = canonical_order(open_tasks)
        if not weighted(tasks):
            return self._path(current, tasks)
        planned: list[PlanTask] = []
        for weight in sorted({task.weight for task in tasks}, reverse=True):
            layer = self._path(current, [task for task in tasks if task.weight == weight])
            planned.extend(layer)
            current = layer[-1].position
        return planned

    def _path(self, current: Position, tasks: Sequence[PlanTask]) -> list[PlanTask]:
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

    def plan(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """`route`: the first task is `next_task`'s (there is no state to change)."""
        return self.route(current, open_tasks, now_s)

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
    stops after `node_limit` nodes (about 10 s; a count, not a clock, so that runs repeat) and,
    as the original implementation did at its 10 s cap, halves the batch (the earlier half)
    and solves that, until the search proves its tour optimal (Held-Karp always does), so
    `state()["exact"]` says True once a tour is planned.

    Weighted: the batch is the `tour_limit` longest weighted waiting (see `waiting_order`)
    instead of the earliest requested; its tour stays the shortest.

    State: the ids of the tour in progress and whether it was proven optimal.
    """

    name: str = "gated-tsp"
    retargets: bool = False
    stands_by: bool = False

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

    def next_task(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> PlanTask | None:
        """The next task of the tour in progress; starts a new tour when that one is done.

        Returns None when no task is open. Raises ValueError on duplicate ids or bad costs.
        """
        tasks = waiting_order(open_tasks, now_s)
        by_id = {task.id: task for task in tasks}
        self._tour = [task_id for task_id in self._tour if task_id in by_id]
        if not self._tour:
            if not tasks:
                self._exact = True
                return None
            self._tour, self._exact = self._plan(current, tasks[: self.tour_limit])
        return by_id[self._tour[0]]

    def route(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """The tour in progress (or the one `next_task` would start), then the later batches.

        Later batches (the next `tour_limit` earliest waiting tasks, from where the previous
        batch ends) are only a preview ordered by the `tour` heuristic: their exact tour is
        computed when the vehicle gets there, with the tasks open then.
        """
        tasks = waiting_order(open_tasks, now_s)
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

    def plan(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """`next_task` (which may start a tour), then `route` over the tour it keeps."""
        if self.next_task(current, open_tasks, now_s) is None:
            return []
        return self.route(current, open_tasks, now_s)

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
        while True:
            matrix = build_cost_matrix(self.cost, current, [task.position for task in batch])
            result = solve_open_path(
                matrix, held_karp_limit=self.held_karp_limit, node_limit=self.node_limit
            )
            if result.exact or len(batch) <= 1:
                break
            batch = batch[: len(batch) // 2]  # the search hit its cap: the earlier half
        tour = [batch[node - 1].id for node in result.path[1:]]
        self._last_plan = (current, key, tour, result.exact)
        return list(tour), result.exact


class LatencyPlanner:
    """The project's default: the order that keeps the customers waiting least.

    It minimises the sum over the open requests of the time until each is complete (the
    traveling-repairman objective: a point task is a request, an `executeAll` batch is one
    request complete at its last task), each request weighted by its age: weight 1 until
    `grace_s`, then 1 more per `tau_s` of waiting, so that a far task cannot be put off for
    ever; a task older than `max_wait_s` is overdue and weighs `OVERDUE_WEIGHT` times more,
    which puts it ahead of everything but a negligible detour. Costs are travel times
    (`TravelTime` of the vehicle) when the caller gives them, so a climb counts as much as the
    distance. A request's age weight is multiplied by its `PlanTask.weight` (a batch's: the
    largest of its tasks'), so the objective is the customers' weighted waiting.

    How: up to `exact_limit` tasks, exactly (dynamic programming over subsets). Above, the
    better of the previous plan with the new tasks inserted where they cost least and a greedy
    order, improved by moving stretches of 1-3 tasks and reversing stretches (constant-time
    evaluation of each move; from the previous plan, the search looks first where it changed
    and then wherever a move it takes leads, not at every task again), then perturbed and
    repaired `kicks` times (none by default: measured on the demo5 protocol, kicks change the
    latencies by less than 1 % and triple the planning time, because the plan is redone at
    every event anyway). When every open task
    belongs to one batch (a survey), the objective is the length of the path: iterated
    2-opt/Or-opt with double-bridge kicks (`iterated_local_search`), about 0.5 % above the
    best known tour at 200 points in under a second, planned once: at each stop the rest of the
    path is kept until new work comes. `time_limit_s` (None: no limit, results
    reproducible) stops a search early. Measured on a 2-core machine: 3.5 ms to replan 100
    open tasks when one arrives, 0.2 s for 1,000 (docs/benchmarks.md).

    The vehicle asks again whenever tasks arrive, in flight too (`retargets`), and an idle
    vehicle waits in the air at the centre of its area for a while (`stands_by`).

    State: the planned order of task ids, the starting point of the next round.
    """

    name: str = "latency"
    retargets: bool = True
    stands_by: bool = True
    OVERDUE_WEIGHT = 1000.0

    def __init__(
        self,
        cost: CostFn = distance_m,
        *,
        grace_s: float = 30.0,
        tau_s: float = 30.0,
        max_wait_s: float = 300.0,
        exact_limit: int = 8,
        kicks: int = 0,
        survey_kicks: int = 2000,
        time_limit_s: float | None = None,
    ) -> None:
        self.cost = cost
        self.grace_s = grace_s
        self.tau_s = tau_s
        self.max_wait_s = max_wait_s
        self.exact_limit = exact_limit
        self.kicks = kicks
        self.survey_kicks = survey_kicks
        self.time_limit_s = time_limit_s
        self._route: list[int] = []
        self._last: tuple[Any, list[int]] | None = None
        self._known = TaskCosts()

    def weight(self, age_s: float) -> float:
        """How much one second of a request's completion counts, by the request's age."""
        weight = 1.0 + max(0.0, age_s - self.grace_s) / self.tau_s
        if age_s >= self.max_wait_s:
            weight *= self.OVERDUE_WEIGHT
        return weight

    def next_task(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> PlanTask | None:
        """The first task of `route`, which becomes the plan to start from next time."""
        planned = self.route(current, open_tasks, now_s)
        self._route = [task.id for task in planned]
        return planned[0] if planned else None

    def plan(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """`route`, which becomes the plan to start from next time (as `next_task` does)."""
        planned = self.route(current, open_tasks, now_s)
        self._route = [task.id for task in planned]
        return planned

    def route(
        self, current: Position, open_tasks: Sequence[PlanTask], now_s: float | None = None
    ) -> list[PlanTask]:
        """All open tasks in the order that minimises the weighted waiting (see the class)."""
        tasks = canonical_order(open_tasks)
        if not tasks:
            return []
        key = (current, tuple(tasks), now_s, tuple(self._route))
        if self._last is not None and self._last[0] == key:
            order = self._last[1]
        else:
            order = self._plan(current, tasks, now_s)
            self._last = (key, order)
        return [tasks[node - 1] for node in order[1:]]

    def _plan(self, current: Position, tasks: Sequence[PlanTask], now_s: float | None) -> list[int]:
        deadline = None if self.time_limit_s is None else time.perf_counter() + self.time_limit_s
        now = max(task.requested_s for task in tasks) if now_s is None else now_s
        matrix = build_cost_matrix(
            self.cost, current, [task.position for task in tasks], known=self._known
        )
        group_ids: dict[Any, int] = {}
        groups = [-1] + [
            group_ids.setdefault(
                task.group if task.group is not None else ("task", task.id), len(group_ids)
            )
            for task in tasks
        ]
        ages: dict[int, float] = {}
        classes: dict[int, float] = {}
        for node, task in enumerate(tasks, start=1):
            ages[groups[node]] = max(ages.get(groups[node], 0.0), now - task.requested_s)
            classes[groups[node]] = max(classes.get(groups[node], 0.0), task.weight)
        weights = [0.0] + [
            self.weight(ages[groups[node]]) * classes[groups[node]]
            for node in range(1, len(tasks) + 1)
        ]
        n = len(tasks)
        if n <= self.exact_limit:
            return exact_path(matrix, weights, groups)[0]
        node_of = {task.id: node for node, task in enumerate(tasks, start=1)}
        kept = [node_of[task_id] for task_id in self._route if task_id in node_of]
        if len(group_ids) == 1:
            if len(kept) == n:
                return [0, *kept]  # a survey under way, nothing new: the rest of its path
            return iterated_local_search(
                matrix, greedy_chain(matrix), kicks=self.survey_kicks, deadline=deadline
            )
        search = RepairmanSearch(matrix, weights, groups, deadline=deadline)
        warm = [0, *kept]
        planned = set(kept)
        inserted = [node for node in range(1, n + 1) if node not in planned]
        for node in inserted:
            warm = search.insert(warm, node)
        greedy = greedy_path(matrix, weights)
        best = min([warm, greedy], key=search.objective)
        if kept and best is warm:
            # The previous plan, a local optimum of the search, with what changed since: the
            # search looks again where it changed (the new tasks, where they went, the first
            # task, which now starts from here) and wherever a move it takes leads.
            touched = {warm[1], *inserted}
            for node in inserted:
                k = warm.index(node)
                touched.update(warm[j] for j in (k - 1, k + 1) if 0 < j < len(warm))
            best = search.improve(warm, start=[node for node in warm if node in touched])
        else:
            best = search.improve(best)
        return search.perturb(best, kicks=self.kicks)

    def state(self) -> dict[str, Any]:
        """{"route": [the planned task ids, in order]}."""
        return {"route": list(self._route)}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Start from a snapshot's plan; {} (or another planner's snapshot) means none.

        Raises ValueError when "route" is not a list of integer ids.
        """
        route = state.get("route", [])
        if not isinstance(route, list) or not all(
            isinstance(task_id, int) and not isinstance(task_id, bool) for task_id in route
        ):
            raise ValueError(f"latency state: 'route' must be a list of task ids, not {route!r}")
        self._route = list(route)
        self._last = None


def node_weights(tasks: Sequence[PlanTask]) -> np.ndarray[Any, np.dtype[np.float64]]:
    """The tasks' weights by node of their cost matrix (node 0, the vehicle: 1)."""
    return np.asarray([1.0, *(task.weight for task in tasks)], dtype=np.float64)


def make_planner(
    name: str,
    *,
    cost: CostFn | None = None,
    travel_time: TravelTime | None = None,
    time_limit_s: float | None = None,
    airspace: Airspace | None = None,
) -> Planner:
    """A new planner of the given name (one of `PLANNER_NAMES`).

    `cost` between points, when given, is what every planner uses. Otherwise `latency` uses
    the vehicle's `travel_time` (seconds, climbs included) when given and the others use
    `distance_m`, as the paper and the original implementation did. With an `airspace` that
    has no-fly zones, every cost is taken along the way around them (`AroundZones`).
    `time_limit_s` bounds the time `latency` spends on one route (None: no bound,
    reproducible results). Raises ValueError naming the unknown name and listing the valid
    ones.
    """
    metres: CostFn = cost or distance_m
    timed: CostFn = cost or travel_time or distance_m
    if airspace:
        metres, timed = AroundZones(metres, airspace), AroundZones(timed, airspace)
    if name == "latency":
        return LatencyPlanner(timed, time_limit_s=time_limit_s)
    if name == "tour":
        return TourPlanner(metres)
    if name == "nearest":
        return NearestPlanner(metres)
    if name == "gated-tsp":
        return GatedTspPlanner(metres)
    if name == "fcfs":
        return FcfsPlanner()
    raise ValueError(f"unknown planner {name!r}; valid planners: {', '.join(PLANNER_NAMES)}")
