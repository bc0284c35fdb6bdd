"""Task sets in metres around an origin, and brute-force optima to compare planners with."""

from __future__ import annotations

import itertools
import random
from collections.abc import Sequence

from fleet.geo import Position, distance_m, offset
from vvm_worker.planning import CostFn, PlanTask

ORIGIN = Position(48.11, 12.86, 20.0)


def task(
    task_id: int,
    north_m: float,
    east_m: float,
    up_m: float = 0.0,
    *,
    requested_s: float | None = None,
) -> PlanTask:
    """A task north_m / east_m / up_m from ORIGIN, requested at its id unless told otherwise."""
    return PlanTask(
        task_id,
        offset(ORIGIN, north_m=north_m, east_m=east_m, up_m=up_m),
        float(task_id) if requested_s is None else requested_s,
    )


def random_tasks(
    count: int, seed: int, *, spread_m: float = 500.0, first_id: int = 1
) -> list[PlanTask]:
    """`count` tasks spread uniformly over a square of +-spread_m around ORIGIN, 0-40 m up."""
    rng = random.Random(seed)
    return [
        task(
            first_id + k,
            rng.uniform(-spread_m, spread_m),
            rng.uniform(-spread_m, spread_m),
            rng.uniform(0.0, 40.0),
            requested_s=rng.uniform(0.0, 100.0),
        )
        for k in range(count)
    ]


def path_length(start: Position, order: Sequence[PlanTask], cost: CostFn = distance_m) -> float:
    """Cost of flying from start through the tasks in order (no return)."""
    total = 0.0
    here = start
    for item in order:
        total += cost(here, item.position)
        here = item.position
    return total


def brute_force_length(
    start: Position, tasks: Sequence[PlanTask], cost: CostFn = distance_m
) -> float:
    """The cheapest open path through all tasks, by trying every order (keep to 8 tasks)."""
    n = len(tasks)
    from_start = [cost(start, t.position) for t in tasks]
    between = [[cost(a.position, b.position) for b in tasks] for a in tasks]
    best = float("inf")
    for perm in itertools.permutations(range(n)):
        total = from_start[perm[0]]
        for a, b in itertools.pairwise(perm):
            total += between[a][b]
        best = min(best, total)
    return best
