"""Cost matrices: the default cost's fast path agrees with fleet.geo.distance_m."""

from __future__ import annotations

import numpy as np
import pytest

from fleet.geo import Position, distance_m
from tests.vvm_worker.planning.support import ORIGIN, random_tasks
from vvm_worker.planning.costs import (
    EXACT_DEFAULT_LIMIT,
    TaskCosts,
    TravelTime,
    approximate_distance_matrix,
    build_cost_matrix,
)


@pytest.mark.parametrize("spread_m", [50.0, 3000.0, 20000.0])
def test_vectorised_distances_match_distance_m(spread_m: float) -> None:
    positions = [t.position for t in random_tasks(40, seed=3, spread_m=spread_m)]
    approximate = approximate_distance_matrix(positions)
    exact = np.array([[distance_m(a, b) for b in positions] for a in positions])
    assert np.allclose(approximate, exact, rtol=1e-7, atol=1e-6)


def test_large_sets_use_the_fast_path_but_keep_exact_costs_from_the_vehicle() -> None:
    positions = [t.position for t in random_tasks(EXACT_DEFAULT_LIMIT + 6, seed=4)]
    matrix = build_cost_matrix(distance_m, ORIGIN, positions)
    assert matrix.symmetric
    assert matrix.values[0, 1:].tolist() == [distance_m(ORIGIN, p) for p in positions]
    assert matrix.values[5, 9] == pytest.approx(distance_m(positions[4], positions[8]), rel=1e-7)


def test_custom_costs_are_used_in_both_directions() -> None:
    positions = [t.position for t in random_tasks(5, seed=6)]

    def uphill_costs_more(a: Position, b: Position) -> float:
        return distance_m(a, b) + 10.0 * max(0.0, b.alt - a.alt)

    matrix = build_cost_matrix(uphill_costs_more, ORIGIN, positions)
    assert not matrix.symmetric
    for i, a in enumerate(positions):
        for j, b in enumerate(positions):
            if i != j:
                assert matrix.values[i + 1, j + 1] == uphill_costs_more(a, b)


def test_a_replan_copies_the_pairs_it_knows_and_gets_the_same_matrix() -> None:
    calls: list[tuple[Position, Position]] = []

    class CountedTravel(TravelTime):
        def __call__(self, a: Position, b: Position) -> float:
            calls.append((a, b))
            return super().__call__(a, b)

    travel = CountedTravel(max_speed_mps=12.0)
    pool = [t.position for t in random_tasks(30, seed=8)]
    known = TaskCosts()
    # One task served, one new, one twice at the same place, the order shuffled.
    rounds = [pool[:20], pool[1:21], [pool[21], *pool[2:21], pool[5]], pool[25:30]]
    computed = []
    for positions in rounds:
        fresh = build_cost_matrix(travel, ORIGIN, positions)
        calls.clear()
        reused = build_cost_matrix(travel, ORIGIN, positions, known=known)
        computed.append(len(calls) - len(positions))  # less the vehicle's row
        assert reused.symmetric
        assert np.array_equal(reused.values, fresh.values)
    # The first time every pair; then only the pairs with a task not seen the time before.
    assert computed == [20 * 19 // 2, 19, 20, 5 * 4 // 2]
