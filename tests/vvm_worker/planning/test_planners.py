"""Behaviour every planner shares, and the nearest, fcfs and tour planners."""

from __future__ import annotations

import json
import random

import pytest

from fleet.geo import Position, distance_m
from tests.vvm_worker.planning.support import (
    ORIGIN,
    brute_force_length,
    path_length,
    random_tasks,
    task,
)
from vvm_worker.planning import (
    DEFAULT_PLANNER,
    PLANNER_NAMES,
    TourPlanner,
    make_planner,
)


def climb_is_expensive(a: Position, b: Position) -> float:
    """Every metre of altitude change costs as much as 20 metres of horizontal flight."""
    return distance_m(a.with_alt(0.0), b.with_alt(0.0)) + 20.0 * abs(b.alt - a.alt)


def test_make_planner_builds_every_named_planner() -> None:
    assert DEFAULT_PLANNER == "latency"
    assert set(PLANNER_NAMES) == {"latency", "tour", "nearest", "gated-tsp", "fcfs"}
    for name in PLANNER_NAMES:
        assert make_planner(name).name == name


def test_unknown_planner_name_is_refused_with_the_valid_names() -> None:
    with pytest.raises(ValueError, match="'shortest'") as error:
        make_planner("shortest")
    for name in PLANNER_NAMES:
        assert name in str(error.value)


@pytest.mark.parametrize("name", PLANNER_NAMES)
def test_no_open_tasks_means_nothing_to_do(name: str) -> None:
    planner = make_planner(name)
    assert planner.next_task(ORIGIN, []) is None
    assert planner.route(ORIGIN, []) == []
    assert json.loads(json.dumps(planner.state())) == planner.state()


@pytest.mark.parametrize("name", PLANNER_NAMES)
def test_duplicate_task_ids_are_refused(name: str) -> None:
    with pytest.raises(ValueError, match=r"\[7\]"):
        make_planner(name).next_task(ORIGIN, [task(7, 10, 0), task(7, 20, 0, requested_s=3.0)])


@pytest.mark.parametrize("name", PLANNER_NAMES)
def test_route_starts_with_next_task_and_leaves_the_state_alone(name: str) -> None:
    tasks = random_tasks(25, seed=3)
    planner = make_planner(name)
    before = planner.state()
    planned = planner.route(ORIGIN, tasks)
    assert planner.state() == before
    assert sorted(t.id for t in planned) == sorted(t.id for t in tasks)
    assert planner.next_task(ORIGIN, tasks) == planned[0]
    assert planner.route(ORIGIN, tasks) == planned


@pytest.mark.parametrize("name", PLANNER_NAMES)
def test_the_order_tasks_are_listed_in_does_not_matter(name: str) -> None:
    tasks = random_tasks(20, seed=11)
    shuffled = list(tasks)
    random.Random(5).shuffle(shuffled)
    assert make_planner(name).route(ORIGIN, tasks) == make_planner(name).route(ORIGIN, shuffled)


def test_nearest_picks_the_closest_task_in_space() -> None:
    far_but_level = task(1, 0, 40)
    near_but_above = task(2, 0, 10, up_m=30)  # 31.6 m away
    nearest = task(3, -25, 5, up_m=-5)  # 26 m away
    planner = make_planner("nearest")
    assert planner.next_task(ORIGIN, [far_but_level, near_but_above, nearest]) == nearest


def test_nearest_breaks_ties_by_request_time_then_id() -> None:
    east = task(5, 0, 30, requested_s=2.0)
    west = task(4, 0, -30, requested_s=2.0)
    north_late = task(1, 30, 0, requested_s=9.0)
    planner = make_planner("nearest")
    assert planner.next_task(ORIGIN, [north_late, east, west]) == west
    earlier = task(6, 0, 30, requested_s=1.0)
    assert planner.next_task(ORIGIN, [north_late, east, west, earlier]) == earlier


def test_nearest_follows_a_line_of_points_in_order() -> None:
    line = [task(k, 0, 15.0 * k, requested_s=100.0 - k) for k in range(1, 9)]
    planner = make_planner("nearest")
    assert [t.id for t in planner.route(ORIGIN, list(reversed(line)))] == list(range(1, 9))
    served = []
    here, open_tasks = ORIGIN, list(line)
    while open_tasks:
        chosen = planner.next_task(here, open_tasks)
        assert chosen is not None
        served.append(chosen.id)
        here = chosen.position
        open_tasks.remove(chosen)
    assert served == list(range(1, 9))


def test_fcfs_serves_by_request_time_then_id() -> None:
    tasks = [
        task(3, 10, 0, requested_s=5.0),
        task(1, 900, 0, requested_s=7.0),
        task(2, 500, 0, requested_s=5.0),
        task(9, 1, 0, requested_s=0.5),
    ]
    planner = make_planner("fcfs")
    assert [t.id for t in planner.route(ORIGIN, tasks)] == [9, 2, 3, 1]
    assert planner.next_task(ORIGIN, tasks) == tasks[3]


@pytest.mark.parametrize("name", ["latency", "nearest", "tour", "gated-tsp"])
def test_a_custom_cost_changes_the_choice(name: str) -> None:
    # 30 m east on the level, or 12 m north but 10 m higher.
    level = task(1, 0, 30)
    above = task(2, 12, 0, up_m=10)
    tasks = [level, above]
    assert make_planner(name).next_task(ORIGIN, tasks) == above
    assert make_planner(name, cost=climb_is_expensive).next_task(ORIGIN, tasks) == level


def test_a_cost_function_must_return_finite_non_negative_costs() -> None:
    tasks = random_tasks(3, seed=1)

    def broken(a: Position, b: Position) -> float:
        return -1.0 if b == tasks[1].position else 1.0

    for name in ("latency", "nearest", "tour", "gated-tsp"):
        with pytest.raises(ValueError, match="finite and not negative"):
            make_planner(name, cost=broken).next_task(ORIGIN, tasks)


def test_stateless_planners_ignore_any_snapshot() -> None:
    tasks = random_tasks(12, seed=2)
    for name in ("tour", "nearest", "fcfs"):
        planner = make_planner(name)
        expected = planner.route(ORIGIN, tasks)
        planner.restore({"tour": [999, 1000], "exact": False})
        assert planner.state() == {}
        assert planner.route(ORIGIN, tasks) == expected


@pytest.mark.parametrize("seed", range(6))
def test_tour_is_optimal_on_small_sets(seed: int) -> None:
    tasks = random_tasks(3 + seed, seed=100 + seed)
    planned = make_planner("tour").route(ORIGIN, tasks)
    assert path_length(ORIGIN, planned) == pytest.approx(brute_force_length(ORIGIN, tasks))


def test_tour_heuristic_is_close_to_optimal_on_small_sets() -> None:
    # exact_limit=0 forces the heuristic (nearest neighbour + 2-opt/Or-opt) even on 8 tasks.
    heuristic = TourPlanner(exact_limit=0)
    gaps = []
    for seed in range(12):
        tasks = random_tasks(8, seed=200 + seed)
        optimum = brute_force_length(ORIGIN, tasks)
        gaps.append(path_length(ORIGIN, heuristic.route(ORIGIN, tasks)) / optimum - 1.0)
    assert max(gaps) < 0.05
    assert sum(gap < 1e-9 for gap in gaps) >= 9  # optimal on most sets


@pytest.mark.parametrize("count", [12, 40, 150])
def test_tour_is_never_longer_than_nearest_neighbour(count: int) -> None:
    for seed in range(4):
        tasks = random_tasks(count, seed=count * 10 + seed)
        tour = path_length(ORIGIN, make_planner("tour").route(ORIGIN, tasks))
        nearest = path_length(ORIGIN, make_planner("nearest").route(ORIGIN, tasks))
        assert tour <= nearest + 1e-6
    # ... and usually clearly shorter once there are many tasks.
    if count >= 40:
        assert tour < 0.95 * nearest


def test_tour_with_a_thousand_tasks_visits_each_once() -> None:
    tasks = random_tasks(1000, seed=42, spread_m=3000.0)
    planner = make_planner("tour")
    planned = planner.route(ORIGIN, tasks)
    assert sorted(t.id for t in planned) == sorted(t.id for t in tasks)
    assert planner.next_task(ORIGIN, tasks) == planned[0]
    nearest = path_length(ORIGIN, make_planner("nearest").route(ORIGIN, tasks))
    assert path_length(ORIGIN, planned) < 0.92 * nearest


def test_tour_takes_new_tasks_into_account_at_once() -> None:
    tasks = [task(1, 0, 100), task(2, 0, 200), task(3, 0, 300)]
    planner = make_planner("tour")
    assert planner.next_task(ORIGIN, tasks) == tasks[0]
    here = tasks[0].position
    newcomer = task(4, 0, 0, requested_s=50.0)
    # From 100 m east: back to the newcomer first (100 + 200 + 100 m) beats leaving it for
    # the end (100 + 100 + 300 m).
    assert [t.id for t in planner.route(here, [*tasks[1:], newcomer])] == [4, 2, 3]
