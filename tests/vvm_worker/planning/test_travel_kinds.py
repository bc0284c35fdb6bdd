"""Travel times of vehicles that dive slower than they rise, and fleets of every kind in the
planners' arena."""

from __future__ import annotations

import random

import numpy as np
import pytest

from fleet.geo import Position, offset
from tests.vvm_worker.planning.support import ORIGIN, brute_force_length, path_length, task
from vvm_worker.arena import Arena, ArenaTask, ArenaVehicle
from vvm_worker.planning import PlanTask, TravelTime, make_planner
from vvm_worker.planning.costs import EXACT_DEFAULT_LIMIT, build_cost_matrix

SURFACE = ORIGIN.with_alt(0.0)
# A sub that rises at 1 m/s and dives at 0.25 m/s, cruising at 2 m/s.
SUB = TravelTime(max_speed_mps=2.0, climb_rate_mps=1.0, dive_rate_mps=0.25)


def _deep_positions(count: int, seed: int) -> list[Position]:
    rng = random.Random(seed)
    return [
        offset(
            SURFACE,
            north_m=rng.uniform(-300.0, 300.0),
            east_m=rng.uniform(-300.0, 300.0),
            up_m=-rng.uniform(0.0, 60.0),
        )
        for _ in range(count)
    ]


def test_going_down_takes_the_dive_rate_and_coming_up_the_climb_rate() -> None:
    deep = offset(SURFACE, north_m=10.0, east_m=0.0, up_m=-20.0)

    assert SUB(SURFACE, deep) == pytest.approx(20.0 / 0.25)
    assert SUB(deep, SURFACE) == pytest.approx(20.0 / 1.0)
    assert not SUB.symmetric


def test_without_a_dive_rate_descending_takes_the_climb_rate_as_before() -> None:
    travel = TravelTime(10.0, 3.0)
    up = offset(ORIGIN, north_m=30.0, east_m=0.0, up_m=30.0)

    assert travel.symmetric
    assert travel(ORIGIN, up) == travel(up, ORIGIN) == pytest.approx(10.0)
    assert TravelTime(10.0, 3.0, dive_rate_mps=3.0).symmetric


@pytest.mark.parametrize("count", [12, EXACT_DEFAULT_LIMIT + 8])
def test_the_matrix_of_a_sub_holds_its_travel_time_both_ways(count: int) -> None:
    positions = _deep_positions(count, seed=count)

    matrix = build_cost_matrix(SUB, SURFACE, positions)

    assert not matrix.symmetric
    pairwise = np.array([[SUB(a, b) for b in positions] for a in positions])
    # Exact up to EXACT_DEFAULT_LIMIT tasks; above, the ground distance is the vectorised one.
    assert np.allclose(matrix.values[1:, 1:], pairwise, rtol=1e-7, atol=1e-9)
    assert matrix.values[0, 1:].tolist() == [SUB(SURFACE, p) for p in positions]


@pytest.mark.parametrize("count", [12, EXACT_DEFAULT_LIMIT + 8])
def test_the_matrix_of_a_copter_is_unchanged_and_symmetric(count: int) -> None:
    travel = TravelTime(10.0, 3.0)
    positions = [offset(p, north_m=0.0, east_m=0.0, up_m=70.0) for p in _deep_positions(count, 5)]

    matrix = build_cost_matrix(travel, ORIGIN, positions)

    assert matrix.symmetric
    pairwise = np.array([[travel(a, b) for b in positions] for a in positions])
    assert np.allclose(matrix.values[1:, 1:], pairwise, rtol=1e-7, atol=1e-9)
    assert np.array_equal(matrix.values[1:, 1:], matrix.values[1:, 1:].T)


@pytest.mark.parametrize("name", ["latency", "tour"])
def test_planners_find_the_cheapest_order_for_a_sub(name: str) -> None:
    tasks = [PlanTask(k + 1, p, 0.0) for k, p in enumerate(_deep_positions(6, seed=11))]
    planner = make_planner(name, cost=SUB)

    order = planner.route(SURFACE, tasks)

    assert sorted(t.id for t in order) == [t.id for t in tasks]
    if name == "tour":  # the tour minimises the path's length in the cost's units
        assert path_length(SURFACE, order, SUB) == pytest.approx(
            brute_force_length(SURFACE, tasks, SUB)
        )


def test_a_dive_rate_must_be_a_positive_number() -> None:
    with pytest.raises(ValueError, match="dive_rate_mps must be a positive finite number, got 0"):
        TravelTime(2.0, 1.0, dive_rate_mps=0.0)


def _square(half_m: float) -> list[tuple[float, float]]:
    corners = [
        offset(SURFACE, north_m=n * half_m, east_m=e * half_m)
        for n, e in ((-1, -1), (-1, 1), (1, 1), (1, -1), (-1, -1))
    ]
    return [(p.lat, p.lng) for p in corners]


@pytest.mark.parametrize(
    ("kind", "low_m", "high_m"),
    [("ground", 0.0, 0.0), ("surface", 0.0, 0.0), ("underwater", -60.0, 0.0)],
)
def test_a_fleet_of_each_kind_serves_every_task_and_parks_at_home(
    kind: str, low_m: float, high_m: float
) -> None:
    vehicles = [
        ArenaVehicle(
            f"{kind}-{k}",
            offset(SURFACE, north_m=0.0, east_m=100.0 * k),
            _square(400.0),
            max_speed_mps=4.0,
            climb_rate_mps=1.0,
            min_altitude_m=low_m,
            max_altitude_m=high_m,
            kind=kind,
            dive_rate_mps=0.5 if kind == "underwater" else None,
            turn_rate_dps=30.0,
        )
        for k in range(2)
    ]
    rng = random.Random(7)
    tasks = [
        ArenaTask(
            10.0 * k,
            task(k, rng.uniform(-350, 350), rng.uniform(-350, 350)).position.with_alt(
                rng.uniform(low_m, high_m)
            ),
        )
        for k in range(20)
    ]
    arena = Arena(vehicles, tasks, "latency", standby_s=30.0)

    result = arena.run()

    assert all(done >= asked for asked, done in zip(result.requested_s, result.done_s, strict=True))
    end = max(rig.driver.plan_end_s for rig in arena.rigs)
    for rig in arena.rigs:
        assert rig.driver.is_landed_at(end)
        assert rig.driver.position_at(end) == rig.spec.depot
        legs = rig.driver.planned_legs(0.0)
        assert "takeoff" not in {leg.phase for leg in legs}
        if kind == "underwater":
            assert min(leg.end.alt for leg in legs) < -10.0
        else:
            assert {leg.end.alt for leg in legs} == {0.0}
