"""The planners weigh the way around the no-fly zones, not the straight line through them."""

from __future__ import annotations

import itertools
import random

import numpy as np
import pytest
from shapely.geometry import Polygon

from fleet.airspace import Airspace, ExclusionZone
from fleet.geo import Position, distance_m, offset
from vvm_worker.planning import (
    NO_WAY_COST,
    PLANNER_NAMES,
    AroundZones,
    PlanTask,
    TravelTime,
    make_planner,
)
from vvm_worker.planning.costs import EXACT_DEFAULT_LIMIT, build_cost_matrix

GROUND = Position(47.0, 8.0, 0.0)


def at(north_m: float, east_m: float, alt: float = 30.0) -> Position:
    return offset(GROUND, north_m=north_m, east_m=east_m, up_m=alt)


def zone(corners: list[tuple[float, float]]) -> ExclusionZone:
    points = [at(n, e) for n, e in corners]
    return ExclusionZone(Polygon([(p.lng, p.lat) for p in points]))


# A wall 20 m thick from 300 m south to 300 m north, 40 m east of the vehicle.
AIR = Airspace([zone([(-300, 40), (-300, 60), (300, 60), (300, 40)])])
HERE = at(0, 0)


def test_the_cost_of_a_leg_is_the_inner_cost_along_its_way() -> None:
    cost = AroundZones(distance_m, AIR)
    end = at(0, 100)
    way = AIR.way(HERE, end)
    assert way is not None and len(way) > 1
    expected = sum(distance_m(a, b) for a, b in itertools.pairwise([HERE, *way]))
    assert cost(HERE, end) == pytest.approx(expected)
    assert cost(HERE, end) > 6 * distance_m(HERE, end)  # 600 m round, 100 m through
    clear = at(100, -50)
    assert cost(HERE, clear) == distance_m(HERE, clear)
    timed = AroundZones(TravelTime(10.0, 3.0), AIR)
    assert timed(HERE, end) == pytest.approx(expected / 10.0)


def test_a_leg_no_way_makes_costs_the_no_way_cost() -> None:
    box = Airspace(
        [
            zone([(-60, -60), (-60, 60), (-40, 60), (-40, -60)]),
            zone([(40, -60), (40, 60), (60, 60), (60, -60)]),
            zone([(-60, -60), (-60, -40), (60, -40), (60, -60)]),
            zone([(-60, 40), (-60, 60), (60, 60), (60, 40)]),
        ]
    )
    assert AroundZones(distance_m, box)(at(0, -200), at(0, 0)) == NO_WAY_COST


@pytest.mark.parametrize("n", [12, EXACT_DEFAULT_LIMIT + 16])
def test_the_cost_matrix_holds_each_pairs_way(n: int) -> None:
    # Small sets (pair by pair) and large ones (vectorised, then the pairs near a zone).
    rng = random.Random(n)
    points = [at(rng.uniform(-250, 250), rng.uniform(-150, 250)) for _ in range(n)]
    points = [p for p in points if not AIR.holds(p)]
    cost = AroundZones(TravelTime(10.0, 3.0), AIR)
    matrix = build_cost_matrix(cost, HERE, points)
    expected = np.zeros_like(matrix.values)
    for i, a in enumerate([HERE, *points]):
        for j, b in enumerate(points, start=1):
            if i != j:
                expected[i, j] = cost(a, b)
    np.testing.assert_allclose(matrix.values, expected, rtol=1e-5)
    assert (matrix.values > build_cost_matrix(cost.inner, HERE, points).values + 1.0).any()


@pytest.mark.parametrize("name", [n for n in PLANNER_NAMES if n != "fcfs"])
def test_a_planner_serves_first_the_task_that_is_nearer_round_the_zone(name: str) -> None:
    behind = PlanTask(1, at(0, 80), 0.0)  # 80 m straight, about 600 m round the wall
    beside = PlanTask(2, at(200, -100), 0.0)  # 220 m, clear
    tasks = [behind, beside]
    straight = make_planner(name, travel_time=TravelTime(10.0, 3.0))
    around = make_planner(name, travel_time=TravelTime(10.0, 3.0), airspace=AIR)
    assert straight.next_task(HERE, tasks, 0.0) == behind
    assert around.next_task(HERE, tasks, 0.0) == beside


def test_without_zones_the_planner_costs_are_the_straight_ones() -> None:
    planner = make_planner("latency", travel_time=TravelTime(10.0, 3.0), airspace=Airspace([]))
    assert isinstance(planner.cost, TravelTime)  # type: ignore[attr-defined]
