"""Deadlines in a route (vvm_worker.planning.deadlines): a task the planner's order would reach
late moves forward where it is in time, nothing in time becomes late, the task flown to keeps
its place against later deadlines, and without deadlines the order is the planner's."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.geo import Position, distance_m, offset
from vvm_worker.planning import PlanTask, arrivals, by_deadline, deadline_of

pytestmark = pytest.mark.backend_independent("pure planning: no database")

HOME = Position(47.0, 8.0, 10.0)


def leg(a: Position, b: Position) -> float:
    """10 m/s, level: a second for every 10 m."""
    return distance_m(a, b) / 10.0


def task(task_id: int, east_m: float, deadline_s: float | None = None, north_m: float = 0.0):
    return PlanTask(
        task_id, offset(HOME, north_m=north_m, east_m=east_m), 0.0, deadline_s=deadline_s
    )


def ids(route: list[PlanTask]) -> list[int]:
    return [t.id for t in route]


def late(route: list[PlanTask], now_s: float = 0.0) -> list[int]:
    times = arrivals(route, start=HOME, now_s=now_s, leg=leg)
    return [t.id for t, at in zip(route, times, strict=True) if at > deadline_of(t) + 1e-6]


def test_without_deadlines_the_order_is_the_planners() -> None:
    route = [task(1, 500.0), task(2, -300.0), task(3, 100.0)]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg, flying_to=1)) == [1, 2, 3]


def test_a_task_reached_late_moves_to_the_latest_place_where_it_is_in_time() -> None:
    # East 100, 200, 300, 400 m, then the premium task back at 150 m: reached at 65 s along
    # the planner's order, due by 25 s. Before the third task it is reached at 20 s (200 m
    # out, 50 m back) and the rest stays in time; before the second, too, but later is less
    # disruption.
    route = [task(1, 100.0, 200.0), task(2, 200.0), task(3, 300.0), task(4, 400.0)]
    route.append(task(9, 150.0, 25.0, north_m=10.0))
    assert late(route) == [9]
    repaired = by_deadline(route, start=HOME, now_s=0.0, leg=leg)
    assert ids(repaired) == [1, 9, 2, 3, 4]
    assert late(repaired) == []


def test_no_task_in_time_is_made_late_for_another() -> None:
    # Task 1 (due by 11 s, 100 m out) must come first; the premium task 9, 100 m the other
    # way and due by 12 s, cannot be in time without making task 1 late: it stays.
    route = [task(1, 100.0, 11.0), task(9, -100.0, 12.0)]
    assert late(route) == [9]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [1, 9]


def test_a_task_late_everywhere_goes_as_early_as_it_can_without_making_another_late() -> None:
    # Task 9 is 1 km away and due in 50 s at 10 m/s: late wherever it goes. It goes first,
    # read 100 s late instead of 190 s, ahead of a task without a deadline...
    route = [task(1, 100.0), task(9, 1000.0, 50.0)]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [9, 1]
    # ... or of one that stays in time after it (due by 300 s, read at 290 s)...
    route = [task(1, 100.0, 300.0), task(9, 1000.0, 50.0)]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [9, 1]
    assert late(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [9]
    # ... but not ahead of one it would make late (due by 20 s, read at 10 s)...
    route = [task(1, 100.0, 20.0), task(9, 1000.0, 50.0)]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [1, 9]
    # ... nor ahead of one due earlier, late too, unless that one weighs less (a request of a
    # lower class, late anyway, waits for one of a higher class).
    route = [task(2, -500.0, 20.0), task(9, 1000.0, 50.0)]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [2, 9]
    premium = PlanTask(
        9, offset(HOME, north_m=0.0, east_m=1000.0), 0.0, weight=10.0, deadline_s=50.0
    )
    route = [task(2, -500.0, 20.0), premium]
    assert ids(by_deadline(route, start=HOME, now_s=0.0, leg=leg)) == [9, 2]


def test_the_task_flown_to_gives_way_to_an_earlier_deadline_only() -> None:
    # Flying to task 1 (500 m east). Task 9, 100 m west, is due by 30 s: the vehicle turns.
    target = task(1, 500.0, 300.0)
    urgent = task(9, -100.0, 30.0)
    assert ids(by_deadline([target, urgent], start=HOME, now_s=0.0, leg=leg, flying_to=1)) == [
        9,
        1,
    ]
    # The same task due later than the target: the vehicle flies on (even though 9 is late).
    relaxed = task(9, -100.0, 301.0)
    assert ids(by_deadline([target, relaxed], start=HOME, now_s=0.0, leg=leg, flying_to=1)) == [
        1,
        9,
    ]
    # A target without a deadline gives way to any task that would be late.
    free = task(1, 500.0)
    assert ids(by_deadline([free, urgent], start=HOME, now_s=0.0, leg=leg, flying_to=1)) == [
        9,
        1,
    ]


def test_a_task_due_later_never_takes_the_place_of_the_target_even_when_it_would_be_late() -> None:
    # Flying to task 1 (300 m east, due by 60 s); task 2, 20 m west, due by 61 s, would be
    # reached at 62 s after it: late, yet it waits for the target.
    target, later = task(1, 300.0, 60.0), task(2, -20.0, 61.0)
    assert late([target, later]) == [2]
    repaired = by_deadline([target, later], start=HOME, now_s=0.0, leg=leg, flying_to=1)
    assert ids(repaired) == [1, 2]
    # Not flying to anything yet (at a stop, choosing): task 2 goes first, both in time.
    assert ids(by_deadline([target, later], start=HOME, now_s=0.0, leg=leg)) == [2, 1]


def test_the_vehicle_keeps_flying_to_a_late_target_the_planner_would_leave_for_one_due_later():
    # Flying to task 1 (300 m east, due by 20 s: late anyway); the planner would turn to task
    # 2 (20 m west, due by 500 s) first. The target stays first.
    target, later = task(1, 300.0, 20.0), task(2, -20.0, 500.0)
    repaired = by_deadline([later, target], start=HOME, now_s=0.0, leg=leg, flying_to=1)
    assert ids(repaired) == [1, 2]
    # In time after the detour (due by 40 s, reached at 34 s): the planner's order stands.
    target = task(1, 300.0, 40.0)
    repaired = by_deadline([later, target], start=HOME, now_s=0.0, leg=leg, flying_to=1)
    assert ids(repaired) == [2, 1]


def test_the_planners_order_stands_where_no_task_is_late() -> None:
    # The planner serves the near task 2 (due in 120 s) on the way to the target (due in
    # 60 s): both in time, nothing to change.
    near, target = task(2, 20.0, 120.0), task(1, 300.0, 60.0)
    repaired = by_deadline([near, target], start=HOME, now_s=0.0, leg=leg, flying_to=1)
    assert ids(repaired) == [2, 1]


positions = st.tuples(
    st.floats(min_value=-800.0, max_value=800.0), st.floats(min_value=-800.0, max_value=800.0)
)
deadlines = st.one_of(st.none(), st.floats(min_value=1.0, max_value=200.0))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(positions, deadlines), min_size=1, max_size=12))
def test_the_repair_is_a_reordering_that_never_adds_a_late_task(
    specs: list[tuple[tuple[float, float], float | None]],
) -> None:
    route = [
        task(k, east, deadline, north_m=north) for k, ((north, east), deadline) in enumerate(specs)
    ]
    repaired = by_deadline(route, start=HOME, now_s=0.0, leg=leg)
    assert sorted(ids(repaired)) == sorted(ids(route))
    assert len(late(repaired)) <= len(late(route))
    # In time before, in time after: no task in time is sacrificed.
    assert set(late(repaired)) <= set(late(route))
