"""Every planner weighs a request by its service class: a heavy request may go first."""

from __future__ import annotations

import dataclasses
import math

import pytest

from tests.vvm_worker.planning.support import ORIGIN, random_tasks, task
from vvm_worker.planning import PLANNER_NAMES, GatedTspPlanner, PlanTask, make_planner


def heavy(item: PlanTask, weight: float) -> PlanTask:
    return dataclasses.replace(item, weight=weight)


@pytest.mark.parametrize("weight", [0.0, -1.0, math.nan, math.inf])
def test_a_task_weight_must_be_a_positive_number(weight: float) -> None:
    with pytest.raises(ValueError, match=r"task 7: weight .* not a positive number"):
        PlanTask(7, ORIGIN, 0.0, weight=weight)


@pytest.mark.parametrize("name", ["latency", "nearest", "tour"])
def test_a_heavy_request_far_away_goes_before_a_light_one_nearby(name: str) -> None:
    near = task(1, 100.0, 0.0, requested_s=0.0)
    far = task(2, -300.0, 0.0, requested_s=0.0)
    planner = make_planner(name)
    assert planner.next_task(ORIGIN, [near, far], 0.0) == near
    weighted = [near, heavy(far, 8.0)]
    assert make_planner(name).next_task(ORIGIN, weighted, 0.0) == weighted[1]


def test_a_light_weight_does_not_outweigh_the_distance() -> None:
    # Latency: 100 m then 400 m back (light first) against 300 m then 400 m: a weight of 1.2
    # saves less waiting than the detour costs the light request.
    near = task(1, 100.0, 0.0, requested_s=0.0)
    far = heavy(task(2, -300.0, 0.0, requested_s=0.0), 1.2)
    assert make_planner("latency").next_task(ORIGIN, [near, far], 0.0) == near


def test_fcfs_serves_the_longest_weighted_waiting_first() -> None:
    old = task(1, 0.0, 100.0, requested_s=0.0)
    newer = task(2, 0.0, 200.0, requested_s=10.0)
    planner = make_planner("fcfs")
    assert planner.route(ORIGIN, [newer, old], 20.0) == [old, newer]
    # Waited 10 s at weight 4 (40) against 20 s at weight 1.
    assert planner.route(ORIGIN, [heavy(newer, 4.0), old], 20.0)[0].id == 2
    # Waited 2 s at weight 4 (8) against 12 s at weight 1: still the old one.
    assert planner.route(ORIGIN, [heavy(newer, 4.0), old], 12.0)[0].id == 1


def test_gated_tsp_takes_the_heaviest_waiting_into_its_batch() -> None:
    old = task(1, 0.0, 100.0, requested_s=0.0)
    newer = heavy(task(2, 0.0, 200.0, requested_s=10.0), 4.0)
    assert GatedTspPlanner(tour_limit=1).next_task(ORIGIN, [old, newer], 20.0) == newer
    light = dataclasses.replace(newer, weight=1.0)
    assert GatedTspPlanner(tour_limit=1).next_task(ORIGIN, [old, light], 20.0) == old


def test_the_tour_serves_each_weight_in_turn() -> None:
    tasks = [
        task(1, 50.0, 0.0),
        heavy(task(2, -400.0, 0.0), 3.0),
        task(3, 60.0, 10.0),
        heavy(task(4, -420.0, 10.0), 3.0),
    ]
    assert [t.id for t in make_planner("tour").route(ORIGIN, tasks)] == [2, 4, 1, 3]


@pytest.mark.parametrize("name", PLANNER_NAMES)
def test_equal_weights_plan_as_no_weights(name: str) -> None:
    """What matters is how requests weigh against each other: everybody of one class (weight
    1 or any other) is planned exactly as without classes."""
    tasks = random_tasks(14, seed=5)
    for weight in (1.0, 3.0):
        same = [heavy(t, weight) for t in tasks]
        plain, classed = make_planner(name), make_planner(name)
        assert [t.id for t in classed.route(ORIGIN, same, 120.0)] == [
            t.id for t in plain.route(ORIGIN, tasks, 120.0)
        ]
        first = make_planner(name).next_task(ORIGIN, same, 120.0)
        assert first is not None
        assert first.id == classed.route(ORIGIN, same, 120.0)[0].id
