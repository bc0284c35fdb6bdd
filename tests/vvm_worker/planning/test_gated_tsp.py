"""The gated-TSP planner: exact tours over batches of waiting tasks, newcomers wait."""

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
from vvm_worker.planning import GATED_TOUR_LIMIT, GatedTspPlanner, PlanTask, make_planner


def serve(
    planner: GatedTspPlanner, here: Position, open_tasks: list[PlanTask], count: int
) -> tuple[list[int], Position]:
    """Let the vehicle serve `count` tasks (removing them from open_tasks); their ids in order."""
    served = []
    for _ in range(count):
        chosen = planner.next_task(here, open_tasks)
        assert chosen is not None
        served.append(chosen.id)
        open_tasks.remove(chosen)
        here = chosen.position
    return served, here


@pytest.mark.parametrize("seed", range(12))
def test_tour_is_optimal_compared_with_brute_force(seed: int) -> None:
    tasks = random_tasks(3 + seed % 6, seed=seed)
    planner = GatedTspPlanner()
    tour = planner.route(ORIGIN, tasks)
    assert path_length(ORIGIN, tour) == pytest.approx(brute_force_length(ORIGIN, tasks), rel=1e-9)
    assert planner.next_task(ORIGIN, tasks) == tour[0]
    assert planner.state() == {"tour": [t.id for t in tour], "exact": True}


def test_branch_and_bound_tours_are_optimal_too() -> None:
    # held_karp_limit=0 sends even these small sets through the branch and bound.
    for seed in range(6):
        tasks = random_tasks(8, seed=50 + seed)
        tour = GatedTspPlanner(held_karp_limit=0).route(ORIGIN, tasks)
        assert path_length(ORIGIN, tour) == pytest.approx(brute_force_length(ORIGIN, tasks))


def test_tasks_that_arrive_during_a_tour_wait_until_it_is_done() -> None:
    tour_tasks = [task(1, 0, 300), task(2, 0, 600), task(3, 0, 900)]
    planner = GatedTspPlanner()
    open_tasks = list(tour_tasks)
    served, here = serve(planner, ORIGIN, open_tasks, 1)
    assert served == [1]
    # Two newcomers right where the vehicle is, and one on the way.
    newcomers = [task(4, 0, 301, requested_s=10.0), task(5, 1, 300, requested_s=10.0)]
    open_tasks += [*newcomers, task(6, 0, 450, requested_s=11.0)]
    assert planner.route(here, open_tasks)[:2] == [tour_tasks[1], tour_tasks[2]]
    served, here = serve(planner, here, open_tasks, 2)
    assert served == [2, 3]
    # The tour is done: the next one is planned over the waiting tasks, from 900 m east.
    served, _ = serve(planner, here, open_tasks, 3)
    assert served == [6, 4, 5]
    assert planner.next_task(here, open_tasks) is None


def test_the_tour_never_takes_more_than_30_tasks_the_earliest_first() -> None:
    rng = random.Random(8)
    tasks = [
        task(k, rng.uniform(-300, 300), rng.uniform(-300, 300), requested_s=float(40 - k))
        for k in range(1, 36)
    ]
    planner = GatedTspPlanner()
    first = planner.next_task(ORIGIN, tasks)
    tour = planner.state()["tour"]
    assert GATED_TOUR_LIMIT == 30
    assert len(tour) == 30
    assert set(tour) == {t.id for t in sorted(tasks, key=lambda t: t.requested_s)[:30]}
    assert first is not None and first.id == tour[0]
    route = planner.route(ORIGIN, tasks)
    assert [t.id for t in route[:30]] == tour
    assert {t.id for t in route[30:]} == {1, 2, 3, 4, 5}
    served, _ = serve(planner, ORIGIN, list(tasks), 35)
    assert served[:30] == tour


def test_state_survives_a_restart_and_the_same_tour_continues() -> None:
    tasks = random_tasks(20, seed=77)
    original = GatedTspPlanner()
    open_tasks = list(tasks)
    _, here = serve(original, ORIGIN, open_tasks, 4)
    snapshot = json.loads(json.dumps(original.state()))
    assert len(snapshot["tour"]) == 17  # the served task stays at the head until it is gone

    restored = GatedTspPlanner()
    restored.restore(snapshot)
    newcomer = task(99, 0, 0, requested_s=1000.0)
    open_tasks.append(newcomer)
    expected, _ = serve(original, here, list(open_tasks), 17)
    continued, _ = serve(restored, here, list(open_tasks), 17)
    assert continued == expected == [*snapshot["tour"][1:], 99]


def test_restoring_a_state_with_tasks_no_longer_open_is_harmless() -> None:
    tasks = [task(1, 0, 100), task(2, 0, 200)]
    planner = GatedTspPlanner()
    planner.restore({"tour": [17, 2, 18], "exact": True})
    assert planner.next_task(ORIGIN, tasks) == tasks[1]
    assert planner.next_task(tasks[1].position, [tasks[0]]) == tasks[0]
    planner.restore({"tour": [17, 18], "exact": False})
    assert planner.next_task(ORIGIN, tasks) == tasks[0]
    assert planner.state() == {"tour": [1, 2], "exact": True}
    planner.restore({})
    assert planner.state() == {"tour": [], "exact": True}


@pytest.mark.parametrize(
    "state", [{"tour": "1,2"}, {"tour": [1, "2"]}, {"tour": [True]}, {"tour": [], "exact": "yes"}]
)
def test_a_malformed_state_is_refused(state: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="gated-tsp state"):
        GatedTspPlanner().restore(state)


def test_tour_tasks_that_disappear_are_skipped() -> None:
    tasks = [task(1, 0, 100), task(2, 0, 200), task(3, 0, 300), task(4, 0, 400)]
    planner = GatedTspPlanner()
    assert planner.next_task(ORIGIN, tasks) == tasks[0]
    # Task 1 served, task 2 cancelled meanwhile, and a newcomer waits.
    remaining = [tasks[2], tasks[3], task(5, 0, 150, requested_s=9.0)]
    assert planner.next_task(tasks[0].position, remaining) == tasks[2]
    assert planner.state()["tour"] == [3, 4]


def test_route_before_next_task_does_not_start_the_tour() -> None:
    tasks = random_tasks(10, seed=5)
    planner = GatedTspPlanner()
    planned = planner.route(ORIGIN, tasks)
    assert planner.state() == {"tour": [], "exact": True}
    # A task that arrives before the vehicle asks is part of the tour it then starts.
    newcomer = task(99, 0, 0, requested_s=500.0)
    assert planner.next_task(ORIGIN, [*tasks, newcomer]) == newcomer
    assert sorted(planner.state()["tour"]) == sorted([t.id for t in tasks] + [99])

    planner = GatedTspPlanner()
    planned = planner.route(ORIGIN, tasks)
    assert planner.next_task(ORIGIN, tasks) == planned[0]
    assert planner.state()["tour"] == [t.id for t in planned]


def test_a_search_that_hits_its_cap_halves_the_batch_as_the_original_did() -> None:
    # Random asymmetric costs give the 1-tree bound no geometry to exploit, so one search node
    # cannot prove optimality.
    tasks = random_tasks(18, seed=9)
    rng = random.Random(4)
    table = {(a.position, b.position): rng.uniform(1, 100) for a in tasks for b in tasks}
    table.update({(ORIGIN, t.position): rng.uniform(1, 100) for t in tasks})

    def arbitrary(a: Position, b: Position) -> float:
        return table[(a, b)]

    planner = GatedTspPlanner(cost=arbitrary, node_limit=1)
    planner.next_task(ORIGIN, tasks)
    state = planner.state()
    earliest = sorted(tasks, key=lambda t: (t.requested_s, t.id))[:9]
    assert sorted(state["tour"]) == sorted(t.id for t in earliest)
    assert state["exact"] is True  # 9 tasks: Held-Karp proves it
    assert brute_force_length(ORIGIN, earliest, arbitrary) == pytest.approx(
        path_length(ORIGIN, planner.route(ORIGIN, tasks)[:9], arbitrary)
    )


def test_make_planner_passes_the_cost_to_the_tour() -> None:
    def only_altitude(a: Position, b: Position) -> float:
        return abs(a.alt - b.alt) + 1e-3 * distance_m(a, b)

    tasks = [task(1, 0, 10, up_m=30), task(2, 0, 500, up_m=10), task(3, 0, 20, up_m=20)]
    planner = make_planner("gated-tsp", cost=only_altitude)
    assert [t.id for t in planner.route(ORIGIN, tasks)] == [2, 3, 1]
