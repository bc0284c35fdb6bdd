"""Deadlines: a request of a customer with a service class is to be read by its request time
plus its class's target (`PlanTask.deadline_s`), and a vehicle keeps that promise whenever it
physically can.

A planner orders the open tasks by what keeps the customers waiting least (weighted by class);
`by_deadline` then looks at when the vehicle would reach each task along that order (the
vehicle's own leg times) and moves forward each task it would reach too late, earliest deadline
first, to the latest place in the order where it is in time without making late a task that
was in time. A vehicle flying to a task it will reach late anyway keeps flying to it where the
planner would turn it to one due later (unless that makes late a task in time). A task that
cannot be in time anywhere goes as early as it can without making
late a task that was in time and without passing a task due as early or earlier: when not
every promise can be kept, the one already broken is broken as little as it can be, at the
cost of tasks due later that stay in time (the planner alone would leave a far, late task
behind near ones for as long as its weight lets it). A deadline never turns the vehicle away from the
task it is flying to for a task whose deadline is later: it is put behind a task whose deadline
is earlier when that one would be late otherwise (the vehicle turns mid-leg and comes back to
it later), never behind one due later. (The planner's own order is another matter: the latency
planner may serve a task on the way first, as it does without classes. Overruling it to keep
the target first whenever a later deadline came first, or whenever the target would then be
late, was measured: it made the premium class's p95 worse in 3 of 18 cases of
`make bench-service-levels` and better in none; docs/benchmarks.md.)

With no deadline among the tasks the order is the planner's, untouched: a fleet without
service classes plans exactly as without this module.

Cost: one pass over the order to time it, then for each late task one pass back from where it
is (three leg times a place), and one pass to time the order again after each move; nothing
more when no task is late.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from fleet.geo import Position

from .base import PlanTask

LegTime = Callable[[Position, Position], float]
"""Seconds the vehicle needs from the first position to the second."""

# Rounding between the sum of legs and a deadline set to it exactly.
_EPS_S = 1e-6


def deadline_of(task: PlanTask) -> float:
    """The task's deadline; a task without one can wait for ever."""
    return math.inf if task.deadline_s is None else task.deadline_s


def arrivals(
    order: Sequence[PlanTask], *, start: Position, now_s: float, leg: LegTime
) -> list[float]:
    """When the vehicle, at ``start`` at ``now_s``, reaches each task flying ``order``."""
    times, t_s, here = [], now_s, start
    for task in order:
        t_s += leg(here, task.position)
        here = task.position
        times.append(t_s)
    return times


def by_deadline(
    order: Sequence[PlanTask],
    *,
    start: Position,
    now_s: float,
    leg: LegTime,
    flying_to: int | None = None,
) -> list[PlanTask]:
    """``order`` (a planner's route from ``start`` at ``now_s``) with the tasks it would reach
    after their deadlines moved forward where they are in time (see the module);
    ``flying_to``: the task the vehicle is flying to now, if any."""
    route = list(order)
    if not any(task.deadline_s is not None for task in route):
        return route
    times = arrivals(route, start=start, now_s=now_s, leg=leg)
    times = _keep_late_target(route, times, flying_to, start=start, now_s=now_s, leg=leg)
    pinned = route[0] if flying_to is not None and route and route[0].id == flying_to else None
    tried: set[int] = set()
    while True:
        late = [
            k
            for k, task in enumerate(route)
            if times[k] > deadline_of(task) + _EPS_S and task.id not in tried
        ]
        if not late:
            return route
        j = min(late, key=lambda k: (deadline_of(route[k]), k))
        tried.add(route[j].id)
        i = _in_time_place(route, times, j, start=start, now_s=now_s, leg=leg, pinned=pinned)
        if i is not None:
            route.insert(i, route.pop(j))
            times = arrivals(route, start=start, now_s=now_s, leg=leg)
            if i == 0:
                pinned = route[0] if flying_to is not None else None


def _keep_late_target(
    route: list[PlanTask],
    times: list[float],
    flying_to: int | None,
    *,
    start: Position,
    now_s: float,
    leg: LegTime,
) -> list[float]:
    """The vehicle flies to ``flying_to``; where the planner's order turns it to a task due
    later and would read the target late, it keeps flying to the target (put first), unless
    that makes late a task that was in time. Returns the arrival times of ``route`` as it is
    then."""
    if flying_to is None or not route or route[0].id == flying_to:
        return times
    k = next((k for k, task in enumerate(route) if task.id == flying_to), None)
    if k is None:
        return times
    target = route[k]
    if deadline_of(route[0]) <= deadline_of(target) or times[k] <= deadline_of(target) + _EPS_S:
        return times
    kept = [target, *route[:k], *route[k + 1 :]]
    kept_times = arrivals(kept, start=start, now_s=now_s, leg=leg)
    after = {task.id: t_s for task, t_s in zip(kept, kept_times, strict=True)}
    if all(
        after[task.id] <= deadline_of(task) + _EPS_S
        for task, t_s in zip(route, times, strict=True)
        if task is not target and t_s <= deadline_of(task) + _EPS_S
    ):
        route[:] = kept
        return kept_times
    return times


def _may_pass(task: PlanTask, other: PlanTask) -> bool:
    """Whether ``task``, late wherever it goes, may be read before ``other`` (when that keeps
    ``other`` in time if it is): when ``other`` is due later, or weighs less (a request of a
    lower class, late too, waits for one of a higher class)."""
    return deadline_of(other) > deadline_of(task) or other.weight < task.weight


def _in_time_place(
    route: list[PlanTask],
    times: list[float],
    j: int,
    *,
    start: Position,
    now_s: float,
    leg: LegTime,
    pinned: PlanTask | None,
) -> int | None:
    """The latest place before ``j`` where ``route[j]`` would be in time, moved there, with
    no task in time made late. Where it is in time nowhere: the earliest such place that is not
    ahead of a task due as early or earlier (it is read as little late as it can be, at
    nobody's cost but of those due later and still in time after it); None when there is no
    such place. Place 0 is taken from ``pinned`` (the task flown to) only for an earlier
    deadline."""
    task = route[j]
    n = len(route)

    def slack(k: int) -> float:
        # How much later task k may be reached; a task late already sets no bound here.
        spare = deadline_of(route[k]) - times[k]
        return math.inf if spare < -_EPS_S else spare

    # The tasks after j move by the insertion's delay plus what leaving j saves.
    before_j = start if j == 0 else route[j - 1].position
    if j + 1 < n:
        after = route[j + 1].position
        saved = leg(before_j, after) - leg(before_j, task.position) - leg(task.position, after)
    else:
        saved = -leg(before_j, task.position)
    after_slack = min((slack(k) for k in range(j + 1, n)), default=math.inf)
    between_slack = math.inf  # of the tasks at i..j-1, which move back
    earliest = None  # the earliest place that makes nobody late, if late everywhere
    passing = True  # no task due as early or earlier between here and j
    for i in range(j - 1, -1, -1):
        between_slack = min(between_slack, slack(i))
        passing = passing and _may_pass(task, route[i])
        if i == 0 and pinned is not None and not deadline_of(task) < deadline_of(pinned):
            return earliest
        prev, prev_s = (start, now_s) if i == 0 else (route[i - 1].position, times[i - 1])
        there = leg(prev, task.position)
        delay = there + leg(task.position, route[i].position) - leg(prev, route[i].position)
        if delay > between_slack + _EPS_S or delay + saved > after_slack + _EPS_S:
            continue
        if prev_s + there <= deadline_of(task) + _EPS_S:
            return i
        if passing:
            earliest = i
    return earliest
