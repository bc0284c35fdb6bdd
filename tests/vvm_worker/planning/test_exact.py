"""The exact open-path solvers and the improvement heuristics, on raw cost matrices."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fleet.geo import distance_m
from tests.vvm_worker.planning.support import ORIGIN, random_tasks
from vvm_worker.planning import exact, solve_open_path
from vvm_worker.planning.costs import CostMatrix, build_cost_matrix
from vvm_worker.planning.exact import held_karp
from vvm_worker.planning.heuristics import greedy_chain, improve_path, path_cost


def random_matrix(n: int, seed: int, kind: str) -> CostMatrix:
    """Costs between node 0 and n tasks: points in the plane, or arbitrary (asymmetric) numbers."""
    rng = np.random.default_rng(seed)
    if kind == "plane":
        points = rng.random((n + 1, 2)) * 1000.0
        values = np.sqrt(((points[:, None] - points[None]) ** 2).sum(axis=-1))
    elif kind == "climb":
        # Climbing costs five times the height, descending half of it: asymmetric.
        points = rng.random((n + 1, 3)) * [500.0, 500.0, 60.0]
        flat = np.sqrt(((points[:, None, :2] - points[None, :, :2]) ** 2).sum(axis=-1))
        up = points[None, :, 2] - points[:, None, 2]
        values = flat + np.where(up > 0, 5.0 * up, -0.5 * up)
    elif kind == "one-way":
        # Along a street that is cheap one way and ten times dearer the other way.
        along = rng.permutation(n + 1).astype(float)
        ahead = along[None, :] - along[:, None]
        values = np.where(ahead > 0, ahead, -10.0 * ahead) + rng.random((n + 1, n + 1))
    else:
        values = rng.integers(1, 5, (n + 1, n + 1)).astype(float)
    np.fill_diagonal(values, 0.0)
    values[:, 0] = 0.0
    return CostMatrix(values, symmetric=bool(np.allclose(values[1:, 1:], values[1:, 1:].T)))


def brute_force(matrix: CostMatrix) -> float:
    n = matrix.size - 1
    return min(path_cost(matrix, [0, *perm]) for perm in itertools.permutations(range(1, n + 1)))


def is_open_path(path: list[int], matrix: CostMatrix) -> bool:
    return path[0] == 0 and sorted(path) == list(range(matrix.size))


@pytest.mark.parametrize("kind", ["plane", "climb", "one-way", "small-integers"])
def test_held_karp_and_branch_and_bound_are_optimal(kind: str) -> None:
    for seed in range(5):
        matrix = random_matrix(4 + seed, seed, kind)
        optimum = brute_force(matrix)
        for held_karp_limit in (20, 0):
            result = solve_open_path(matrix, held_karp_limit=held_karp_limit)
            assert is_open_path(result.path, matrix)
            assert result.exact
            assert result.cost == pytest.approx(optimum, rel=1e-9)
            assert path_cost(matrix, result.path) == pytest.approx(result.cost)


@pytest.mark.parametrize("kind", ["plane", "climb", "one-way", "small-integers"])
def test_branch_and_bound_agrees_with_held_karp_on_larger_sets(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Start the search from the plain nearest-neighbour path, so that the search itself (not
    # the heuristic incumbent) has to find the optimum.
    monkeypatch.setattr(exact, "improve_with_restarts", lambda matrix, path, rounds: path)
    for seed in range(12):
        # Arbitrary small integers give the bound little to work with: keep those smaller.
        matrix = random_matrix(10 if kind == "small-integers" else 12, 20 + seed, kind)
        _, optimum = held_karp(matrix)
        result = solve_open_path(matrix, held_karp_limit=0)
        assert result.method == "branch-and-bound" and result.exact
        assert result.cost == pytest.approx(optimum, rel=1e-9)


def test_thirty_geographic_tasks_are_solved_exactly() -> None:
    tasks = random_tasks(30, seed=1)
    matrix = build_cost_matrix(distance_m, ORIGIN, [t.position for t in tasks])
    result = solve_open_path(matrix)
    assert result.exact and result.method == "branch-and-bound"
    assert is_open_path(result.path, matrix)
    improved = improve_path(matrix, greedy_chain(matrix))
    assert result.cost <= path_cost(matrix, improved) + 1e-6


def test_held_karp_prefers_the_earliest_task_among_equal_tours() -> None:
    # Tasks 1 and 2 at the same place, 3 further on the same line: [1, 2, 3] and [2, 1, 3]
    # cost the same; the lower index (earlier request) goes first.
    values = np.array(
        [[0, 5, 5, 9], [0, 0, 0, 4], [0, 0, 0, 4], [0, 4, 4, 0]],
        dtype=float,
    )
    path, cost = held_karp(CostMatrix(values, symmetric=True))
    assert path == [0, 1, 2, 3]
    assert cost == 9.0


def test_improvement_gets_within_a_few_percent_of_the_optimum() -> None:
    gaps = []
    for seed in range(40):
        matrix = random_matrix(12, seed, "plane")
        _, optimum = held_karp(matrix)
        improved = improve_path(matrix, greedy_chain(matrix))
        gaps.append(path_cost(matrix, improved) / optimum - 1.0)
    # Measured: 1.2% above the optimum on average, optimal on 27 of 40 (2-opt moves alone:
    # 2.2%, 18 of 40).
    assert sum(gaps) / len(gaps) < 0.018
    assert sum(gap < 1e-9 for gap in gaps) >= 22


@pytest.mark.parametrize("kind", ["plane", "climb", "one-way"])
def test_improvement_never_makes_a_path_worse_and_keeps_every_node(kind: str) -> None:
    for seed in range(5):
        matrix = random_matrix(60, seed, kind)
        rng = np.random.default_rng(seed)
        start = [0, *(int(k) for k in rng.permutation(np.arange(1, 61)))]
        for initial in (start, greedy_chain(matrix)):
            improved = improve_path(matrix, initial)
            assert is_open_path(improved, matrix)
            assert path_cost(matrix, improved) <= path_cost(matrix, initial) + 1e-9
        improved = improve_path(matrix, start)
        assert path_cost(matrix, improved) < 0.5 * path_cost(matrix, start)
