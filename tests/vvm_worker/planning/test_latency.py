"""The default planner, `latency`: least total waiting, shortest surveys, no starvation."""

from __future__ import annotations

import itertools
import random

import pytest
from shapely.geometry import Point

from fleet.geo import Position, distance_m, offset
from tests.vvm_worker.planning.support import (
    ORIGIN,
    brute_force_length,
    path_length,
    random_tasks,
    task,
)
from vvm_worker.arena import Arena, ArenaTask, ArenaVehicle
from vvm_worker.planning import LatencyPlanner, PlanTask, TravelTime, make_planner
from vvm_worker.planning.costs import build_cost_matrix
from vvm_worker.planning.exact import solve_open_path
from vvm_worker.planning.repairman import RepairmanSearch, greedy_path, group_objective
from vvm_worker.scenario_gen import grid_box, poisson_scenario, poisson_tasks

TRAVEL = TravelTime(10.0, 3.0)


def waiting(planner: LatencyPlanner, order: list[PlanTask], now: float) -> float:
    """The planner's objective for serving `order` from ORIGIN: per request, its weight times
    the time until its last task is read."""
    t, done = 0.0, {}
    weight = {}
    here = ORIGIN
    for item in order:
        t += planner.cost(here, item.position)
        here = item.position
        key = item.group or item.id
        done[key] = t
        weight[key] = planner.weight(now - item.requested_s)
    return sum(weight[k] * done[k] for k in done)


def brute_force_waiting(planner: LatencyPlanner, tasks: list[PlanTask], now: float) -> float:
    """The least objective over every order of the tasks (keep to 8 tasks)."""
    n = len(tasks)
    start = [planner.cost(ORIGIN, t.position) for t in tasks]
    between = [[planner.cost(a.position, b.position) for b in tasks] for a in tasks]
    keys = [t.group or t.id for t in tasks]
    weight = {keys[i]: planner.weight(now - tasks[i].requested_s) for i in range(n)}
    best = float("inf")
    for perm in itertools.permutations(range(n)):
        t = start[perm[0]]
        done = {keys[perm[0]]: t}
        for a, b in itertools.pairwise(perm):
            t += between[a][b]
            done[keys[b]] = t
        best = min(best, sum(weight[k] * v for k, v in done.items()))
    return best


def aged_tasks(count: int, seed: int) -> list[PlanTask]:
    """Tasks within 150 m, requested over the last 200 s (some old enough to weigh more)."""
    rng = random.Random(seed)
    return [
        task(k + 1, rng.uniform(-150, 150), rng.uniform(-150, 150), rng.uniform(-15, 25),
             requested_s=rng.uniform(0, 200))
        for k in range(count)
    ]  # fmt: skip


@pytest.mark.parametrize("seed", range(6))
def test_latency_is_optimal_on_eight_points(seed: int) -> None:
    tasks = aged_tasks(8, seed)
    planner = LatencyPlanner(TRAVEL)
    order = planner.route(ORIGIN, tasks, 200.0)
    assert waiting(planner, order, 200.0) == pytest.approx(
        brute_force_waiting(planner, tasks, 200.0), rel=1e-9
    )


@pytest.mark.parametrize("seed", range(6))
def test_latency_counts_a_batch_as_done_at_its_last_task(seed: int) -> None:
    rng = random.Random(seed)
    tasks = [
        PlanTask(t.id, t.position, t.requested_s, group=rng.choice(["a", "b", None]))
        for t in aged_tasks(8, seed + 100)
    ]
    # One batch is requested at one time: its tasks share the request time of the first.
    first = {t.group: t.requested_s for t in reversed(tasks) if t.group}
    tasks = [PlanTask(t.id, t.position, first.get(t.group, t.requested_s), t.group) for t in tasks]
    planner = LatencyPlanner(TRAVEL)
    order = planner.route(ORIGIN, tasks, 250.0)
    assert waiting(planner, order, 250.0) == pytest.approx(
        brute_force_waiting(planner, tasks, 250.0), rel=1e-9
    )


@pytest.mark.parametrize("seed", range(4))
def test_a_survey_of_eight_points_is_the_shortest_path(seed: int) -> None:
    tasks = [PlanTask(t.id, t.position, 0.0, group="survey") for t in random_tasks(8, seed)]
    order = make_planner("latency").route(ORIGIN, tasks, 0.0)
    assert path_length(ORIGIN, order) == pytest.approx(brute_force_length(ORIGIN, tasks), rel=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_a_survey_of_25_points_is_as_short_as_the_exact_tour(seed: int) -> None:
    tasks = [PlanTask(t.id, t.position, 0.0, group="s") for t in random_tasks(25, seed + 40)]
    order = make_planner("latency").route(ORIGIN, tasks, 0.0)
    matrix = build_cost_matrix(distance_m, ORIGIN, [t.position for t in tasks])
    exact = solve_open_path(matrix)
    assert exact.exact
    assert path_length(ORIGIN, order) <= exact.cost * 1.005


@pytest.mark.parametrize("seed", range(4))
def test_the_search_beats_the_greedy_order_and_nearly_matches_the_optimum(seed: int) -> None:
    tasks = aged_tasks(8, seed + 7)
    planner = LatencyPlanner(TRAVEL, exact_limit=0)  # the heuristic, on a size with an optimum
    best = brute_force_waiting(planner, tasks, 200.0)
    found = waiting(planner, planner.route(ORIGIN, tasks, 200.0), 200.0)
    matrix = build_cost_matrix(TRAVEL, ORIGIN, [t.position for t in tasks])
    weights = [0.0] + [planner.weight(200.0 - t.requested_s) for t in tasks]
    greedy = group_objective(matrix, greedy_path(matrix, weights), weights, [-1, *range(8)])
    assert found <= greedy + 1e-9
    assert found <= best * 1.02


def test_a_replan_after_a_new_task_is_as_good_as_planning_from_scratch() -> None:
    # Replanning when one task is served and another arrives looks again only where the plan
    # changed (and wherever a move leads from there): on average its waiting is that of a
    # search over the whole plan (each is a local optimum, either may be a little better on
    # one instance), for a fraction of its time.
    ratios = []
    for seed in range(16):
        tasks = aged_tasks(41, seed)
        planner = LatencyPlanner(TRAVEL)
        served, new = planner.plan(ORIGIN, tasks[:40], 200.0)[0], tasks[40]
        rest = [t for t in tasks[:40] if t.id != served.id] + [new]
        replanned = planner.plan(served.position, rest, 210.0)
        assert sorted(t.id for t in replanned) == sorted(t.id for t in rest)
        scratch = LatencyPlanner(TRAVEL).plan(served.position, rest, 210.0)

        def objective(order: list[PlanTask], here: Position = served.position) -> float:
            matrix = build_cost_matrix(TRAVEL, here, [t.position for t in order])
            weights = [0.0] + [LatencyPlanner(TRAVEL).weight(210.0 - t.requested_s) for t in order]
            groups = [-1, *range(len(order))]
            return group_objective(matrix, list(range(len(order) + 1)), weights, groups)

        ratios.append(objective(replanned) / objective(scratch))
    assert sum(ratios) / len(ratios) <= 1.01
    assert max(ratios) <= 1.05


def test_moves_are_evaluated_exactly() -> None:
    """The constant-time evaluation of a rearrangement equals the objective of the result."""
    tasks = aged_tasks(30, 5)
    matrix = build_cost_matrix(TRAVEL, ORIGIN, [t.position for t in tasks])
    rng = random.Random(1)
    weights = [0.0] + [rng.uniform(1, 5) for _ in tasks]
    groups = [-1, *range(30)]
    search = RepairmanSearch(matrix, weights, groups)
    path = [0, *rng.sample(range(1, 31), 30)]
    search._load(path)
    checked = 0
    for node in range(1, 31):
        for blocks in search._moves(node):
            expected = group_objective(matrix, search._materialise(blocks), weights, groups)
            assert search._joined(blocks) == pytest.approx(expected, rel=1e-9)
            checked += 1
    assert checked > 100


@pytest.mark.parametrize("count", [50, 1000])
def test_every_task_is_planned_once_and_the_route_starts_with_the_next_task(count: int) -> None:
    tasks = aged_tasks(count, count)
    planner = LatencyPlanner(TRAVEL)
    route = planner.route(ORIGIN, tasks, 200.0)
    assert sorted(t.id for t in route) == sorted(t.id for t in tasks)
    assert planner.next_task(ORIGIN, tasks, 200.0) == route[0]
    assert planner.state() == {"route": [t.id for t in route]}


def test_the_plan_is_reproducible_and_survives_a_restart() -> None:
    tasks = aged_tasks(60, 9)
    first, second = LatencyPlanner(TRAVEL), LatencyPlanner(TRAVEL)
    first.next_task(ORIGIN, tasks[:50], 150.0)
    second.restore(first.state())
    assert first.route(ORIGIN, tasks, 200.0) == second.route(ORIGIN, tasks, 200.0)
    with pytest.raises(ValueError, match="'route'"):
        second.restore({"route": ["7"]})


def test_an_old_task_weighs_more_and_an_overdue_one_goes_first() -> None:
    planner = LatencyPlanner(TRAVEL, grace_s=30, tau_s=30, max_wait_s=300)
    assert planner.weight(0) == planner.weight(30) == 1.0
    assert planner.weight(90) == 3.0
    assert planner.weight(300) == 10.0 * LatencyPlanner.OVERDUE_WEIGHT
    near, far = task(1, -20, 0, requested_s=290.0), task(2, 600, 0, requested_s=0.0)
    assert planner.next_task(ORIGIN, [near, far], 295.0) == near
    assert planner.next_task(ORIGIN, [near, far], 301.0) == far


def one_vehicle(spread_m: float) -> list[ArenaVehicle]:
    corners = [offset(ORIGIN, north_m=n, east_m=e) for n, e in
               ((-spread_m, -spread_m), (-spread_m, spread_m), (spread_m, spread_m), (spread_m, -spread_m))]  # fmt: skip
    ring = [(p.lat, p.lng) for p in corners]
    return [ArenaVehicle("RV", ORIGIN.with_alt(0.0), [*ring, ring[0]], max_altitude_m=100.0)]


def starving_stream() -> list[ArenaTask]:
    """For 20 minutes a near task every 2 s at two points 20 m apart, and after 10 s a far
    task: a near task is always open, so a planner that looks only at distance never flies
    far."""
    far = ArenaTask(10.0, offset(ORIGIN, north_m=450, east_m=450))
    near = [
        ArenaTask(2.0 * k, offset(ORIGIN, north_m=0, east_m=20.0 * (k % 2))) for k in range(600)
    ]
    return [far, *near]


def test_no_task_starves_beyond_the_bound() -> None:
    # Overdue after max_wait_s, then at most the flight there (64 s) and the leg under way.
    bound_s = LatencyPlanner(TRAVEL).max_wait_s + 70.0
    result = Arena(one_vehicle(500.0), starving_stream(), "latency").run()
    assert result.latencies_s[0] <= bound_s
    assert max(result.latencies_s) <= bound_s
    # What the bound prevents: nearest neighbour leaves the far task to the very end.
    result = Arena(one_vehicle(500.0), starving_stream(), "nearest").run()
    assert result.latencies_s[0] > 1000.0


def test_routes_reach_every_task_within_tolerance_and_altitude_limits() -> None:
    scenario = poisson_scenario(mean_gap_s=1.5, seed=3, vvs=1)
    vehicles = [
        ArenaVehicle(v["name"], Position(*v["depot"]), [tuple(p) for p in v["area"]],
                     max_speed_mps=10.0, max_altitude_m=v["max_altitude_m"])
        for v in scenario["vehicles"]
    ]  # fmt: skip
    box = grid_box(rows=2, cols=2, cell_m=200.0)
    tasks = [ArenaTask(t, p) for t, p in poisson_tasks(mean_gap_s=1.5, seed=3, count=120, box=box)]
    arena = Arena(vehicles, tasks, "latency")
    result = arena.run()
    rigs = {rig.spec.name: rig for rig in arena.rigs}
    for task_, done, name in zip(tasks, result.done_s, result.vehicle, strict=True):
        rig = rigs[name]
        assert done >= task_.at_s
        assert distance_m(rig.driver.position_at(done), task_.position) <= 4.0 + 1e-3
        assert rig.polygon.covers(Point(task_.position.lng, task_.position.lat))
    for rig in arena.rigs:
        for leg in rig.driver.planned_legs(0.0):
            assert 0.0 <= leg.end.alt <= rig.spec.max_altitude_m
        assert rig.driver.is_landed_at(rig.driver.plan_end_s)


def test_a_survey_is_planned_once_and_flown_as_planned() -> None:
    tasks = [PlanTask(t.id, t.position, 0.0, group="s") for t in random_tasks(60, 21)]
    planner = LatencyPlanner()
    planned = planner.route(ORIGIN, tasks, 0.0)
    assert planner.next_task(ORIGIN, tasks, 0.0) == planned[0]
    here, left = planned[0].position, [t for t in tasks if t != planned[0]]
    # At the first stop, the rest of the same path: no search, and no change of mind.
    assert planner.route(here, left, 10.0) == planned[1:]
    # New work in the same batch (none of a survey's tasks were known): planned anew, all in.
    extra = PlanTask(999, offset(ORIGIN, north_m=5, east_m=5), 0.0, group="s")
    assert sorted(t.id for t in planner.route(here, [*left, extra], 10.0)) == sorted(
        [t.id for t in left] + [999]
    )
