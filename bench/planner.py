"""``make bench-planner``: the route planners against each other, with figures to record.

1. The original implementation's demo5 protocol (4 RVs at 10 m/s, each its own 200 m cell of
   a 400 m square; 199 VVs with one point task each at 5-55 m up, Poisson arrivals), over a
   sweep of the mean gap between arrivals from 5 s down to where the fleet saturates, on
   several seeds: mean, 95th percentile and maximum task latency (request to reading),
   makespan and distance flown (back at the depots), averaged over the seeds.
2. The same with overlapping areas (each RV's area 100 m wider on every side), once with the
   mapper that knows the RVs' routes (the platform's) and once with the old ranking (distance
   plus 30 s per queued task), to show what assigning by the planner's cost gives.
3. A 200-point survey (`executeAll`): each planner's path length against the best tour known
   (LKH through `elkai` when installed, a reference only: it is not free for commercial use;
   otherwise the project's own search run 25 times longer), and the planning time.
4. Replanning when a task arrives, with 100 and 1,000 tasks open.
5. A check that the arena agrees with ``manage.py simulate`` (the whole platform) on demo5.

The sweeps run in the arena (`vvm_worker.arena`): the RVs' control loop, the mapper and the
planners without programs and database, a hundred times faster than ``simulate``; part 5 shows
both give the same latencies. Prints Markdown tables for docs/benchmarks.md and draws
docs/planner-latency.png (latency against arrival rate, one line per planner).
"""

from __future__ import annotations

import argparse
import itertools
import json
import multiprocessing
import os
import platform
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from fleet.geo import Position, distance_m, offset
from vvm_worker.arena import Arena, ArenaTask, ArenaVehicle
from vvm_worker.planning import PLANNER_NAMES, PlanTask, TravelTime, make_planner
from vvm_worker.planning.costs import build_cost_matrix
from vvm_worker.planning.heuristics import greedy_chain, iterated_local_search, path_cost
from vvm_worker.scenario_gen import grid_box, poisson_scenario, poisson_tasks

ROOT = Path(__file__).resolve().parents[1]
PLOT = ROOT / "docs" / "planner-latency.png"
GAPS = (5.0, 4.0, 3.0, 2.0, 1.5, 1.25, 1.0, 0.75)
OVERLAP_GAPS = (2.0, 1.5, 1.0)
OVERLAP_M = 100.0
VVS = 199


def demo5_fleet(overlap_m: float = 0.0) -> list[ArenaVehicle]:
    scenario = poisson_scenario(mean_gap_s=1.0, seed=0, vvs=1, overlap_m=overlap_m)
    return [
        ArenaVehicle(
            v["name"],
            Position(*v["depot"]),
            [(lat, lng) for lat, lng in v["area"]],
            max_speed_mps=v["max_speed_mps"],
            max_altitude_m=v["max_altitude_m"],
        )
        for v in scenario["vehicles"]
    ]


def demo5_tasks(gap_s: float, seed: int) -> list[ArenaTask]:
    box = grid_box(rows=2, cols=2, cell_m=200.0)
    return [
        ArenaTask(at_s, p)
        for at_s, p in poisson_tasks(mean_gap_s=gap_s, seed=seed, count=VVS, box=box)
    ]


def one_run(job: tuple[str, float, int, float, bool]) -> dict[str, Any]:
    planner, gap_s, seed, overlap_m, routes = job
    result = Arena(
        demo5_fleet(overlap_m), demo5_tasks(gap_s, seed), planner, mapper_knows_routes=routes
    ).run()
    latencies = result.latencies_s
    return {
        "planner": planner,
        "gap_s": gap_s,
        "seed": seed,
        "overlap_m": overlap_m,
        "routes": routes,
        "mean": statistics.fmean(latencies),
        "p95": float(np.percentile(latencies, 95)),
        "max": max(latencies),
        "makespan": result.makespan_s,
        "distance": sum(result.distance_m.values()),
    }


def averaged(runs: list[dict[str, Any]], *keys: str) -> dict[tuple[Any, ...], dict[str, float]]:
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for run in runs:
        groups.setdefault(tuple(run[k] for k in keys), []).append(run)
    return {
        key: {
            m: statistics.fmean(r[m] for r in rs)
            for m in ("mean", "p95", "max", "makespan", "distance")
        }
        for key, rs in groups.items()
    }


def table(
    rows: dict[tuple[Any, ...], dict[str, float]], planners: list[str], gaps: tuple[float, ...]
) -> None:
    print(
        "| mean gap | planner | mean latency | p95 | max | makespan | distance "
        "| mean vs nearest | mean vs gated-tsp |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for gap in gaps:
        for planner in planners:
            r = rows[(gap, planner)]
            versus = [
                f"{(r['mean'] / rows[(gap, other)]['mean'] - 1) * 100:+.1f} %"
                for other in ("nearest", "gated-tsp")
            ]
            print(
                f"| {gap:g} s | {planner} | {r['mean']:.1f} s | {r['p95']:.1f} s | "
                f"{r['max']:.1f} s | {r['makespan']:.0f} s | {r['distance'] / 1000:.2f} km | "
                f"{versus[0]} | {versus[1]} |"
            )


def plot(rows: dict[tuple[Any, ...], dict[str, float]], planners: list[str], seeds: int) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(no plot: matplotlib is not installed; pip install -e '.[bench]')")
        return
    fig, ax = plt.subplots(figsize=(8, 5), dpi=110)
    for planner in planners:
        rates = [1.0 / gap for gap in GAPS]
        ax.plot(rates, [rows[(gap, planner)]["mean"] for gap in GAPS], marker="o", label=planner)
    ax.set_xlabel("arrival rate (tasks per second, 4 RVs)")
    ax.set_ylabel(f"mean task latency (s), average of {seeds} seeds")
    ax.set_title("demo5 protocol: 199 one-task VVs, 4 RVs at 10 m/s in 200 m cells")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    PLOT.parent.mkdir(exist_ok=True)
    fig.savefig(PLOT)
    print(f"\nplot: {PLOT.relative_to(ROOT)}")


# --- the survey ---------------------------------------------------------------------------------


def survey_points(seed: int, count: int = 200) -> list[PlanTask]:
    rng = random.Random(seed)
    origin = Position(48.11, 12.86, 30.0)
    return [
        PlanTask(
            k + 1,
            offset(
                origin,
                north_m=rng.uniform(0, 1000),
                east_m=rng.uniform(0, 1000),
                up_m=rng.uniform(-5, 5),
            ),
            0.0,
            group="survey",
        )
        for k in range(count)
    ]


def best_known(start: Position, tasks: list[PlanTask]) -> tuple[float, str]:
    """The shortest open path from start through the tasks that we can compute offline."""
    matrix = build_cost_matrix(distance_m, start, [t.position for t in tasks])
    try:
        import elkai
    except ImportError:
        path = iterated_local_search(matrix, greedy_chain(matrix), kicks=50_000, seed=7)
        return path_cost(matrix, path), "own search, 50,000 kicks"
    values = matrix.values.copy()
    values[1:, 0] = values[0, 1:]
    m = values.shape[0]
    scaled = np.rint(values * 1000).astype(np.int64)
    big = int(scaled.max()) * 3 + 1
    # An open path from node 0 = a closed tour through a dummy node next to node 0 at no cost
    # and at `big` from everything else.
    full = np.full((m + 1, m + 1), big, dtype=np.int64)
    full[:m, :m] = scaled
    full[m, 0] = full[0, m] = full[m, m] = 0
    tour = elkai.DistanceMatrix(full.tolist()).solve_tsp(runs=10)[:-1]
    k = tour.index(0)
    tour = tour[k:] + tour[:k]
    if tour[1] == m:
        tour = [0, *reversed(tour[1:])]
    path = [node for node in tour if node != m]
    return path_cost(matrix, path), "LKH (elkai), 10 runs"


def survey(seeds: int) -> None:
    start = Position(48.11, 12.86, 0.0)
    ratios: dict[str, list[float]] = {}
    times: dict[str, list[float]] = {}
    how = ""
    for seed in range(1, seeds + 1):
        tasks = survey_points(seed)
        best, how = best_known(start, tasks)
        for name in ("latency", "tour", "nearest", "gated-tsp"):
            planner = make_planner(name, cost=distance_m)
            started = time.perf_counter()
            order = planner.route(start, tasks, 0.0)
            times.setdefault(name, []).append(time.perf_counter() - started)
            stops = [start, *(t.position for t in order)]
            length = sum(distance_m(a, b) for a, b in itertools.pairwise(stops))
            ratios.setdefault(name, []).append(length / best)
    print(f"\n200-point survey, {seeds} seeds, ratio to the best known tour ({how}):\n")
    print("| planner | mean ratio | worst ratio | planning time (median) |")
    print("|---|---:|---:|---:|")
    for name, values in ratios.items():
        print(
            f"| {name} | {statistics.fmean(values):.4f} | {max(values):.4f} | "
            f"{statistics.median(times[name]) * 1000:.0f} ms |"
        )


# --- replanning ---------------------------------------------------------------------------------


def replanning() -> None:
    print("\nReplanning when a task arrives (median of 5, the previous plan in place):\n")
    print("| open tasks | planner | time |")
    print("|---:|---|---:|")
    travel = TravelTime(10.0, 3.0)
    box = grid_box(rows=1, cols=1, cell_m=200.0)
    for count in (100, 1000):
        pool = poisson_tasks(mean_gap_s=1.0, seed=count, count=count + 5, box=box)
        tasks = [PlanTask(k, p, at_s) for k, (at_s, p) in enumerate(pool)]
        here = Position(box["south"], box["west"], 30.0)
        for name in PLANNER_NAMES:
            planner = make_planner(name, travel_time=travel)
            now = tasks[count - 1].requested_s
            planner.next_task(here, tasks[:count], now)
            spent = []
            for extra in range(5):
                open_tasks = tasks[: count + extra + 1]
                started = time.perf_counter()
                planner.next_task(here, open_tasks, open_tasks[-1].requested_s)
                planner.route(here, open_tasks, open_tasks[-1].requested_s)
                spent.append(time.perf_counter() - started)
            print(f"| {count:,} | {name} | {statistics.median(spent) * 1000:.1f} ms |", flush=True)


# --- the arena against simulate -----------------------------------------------------------------


def against_simulate(seeds: list[int], gap_s: float = 1.5) -> None:
    print(f"\nThe arena against `manage.py simulate` (demo5, mean gap {gap_s:g} s):\n")
    print("| planner | seed | simulate: mean latency | arena: mean latency | simulate wall time |")
    print("|---|---:|---:|---:|---:|")
    for planner in ("nearest", "latency"):
        for seed in seeds:
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "demo5.json"
                path.write_text(json.dumps(poisson_scenario(mean_gap_s=gap_s, seed=seed)))
                env = {**os.environ, "CPCC_VAR_DIR": tmp, "CPCC_MEDIA_ROOT": str(Path(tmp) / "m")}
                started = time.perf_counter()
                out = subprocess.run(
                    [sys.executable, "manage.py", "simulate", str(path), "--speed", "0",
                     "--planner", planner, "--json"],
                    cwd=ROOT, env=env, check=True, capture_output=True, text=True,
                )  # fmt: skip
                wall = time.perf_counter() - started
            summary = json.loads(out.stdout.strip().splitlines()[-1])
            simulated = statistics.fmean(
                t["done_s"] - t["requested_s"] for vv in summary["vvs"] for t in vv["tasks"]
            )
            arena = one_run((planner, gap_s, seed, 0.0, True))["mean"]
            print(
                f"| {planner} | {seed} | {simulated:.2f} s | {arena:.2f} s | {wall:.0f} s |",
                flush=True,
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=10, help="seeds per point (default 10)")
    parser.add_argument("--no-simulate", action="store_true", help="skip part 5")
    args = parser.parse_args()
    print(
        f"# {time.strftime('%Y-%m-%d')} · {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}\n"
    )
    planners = ["latency", "tour", "nearest", "gated-tsp", "fcfs"]
    seeds = range(1, args.seeds + 1)
    jobs = [(p, gap, s, 0.0, True) for gap in GAPS for p in planners for s in seeds]
    jobs += [(p, gap, s, OVERLAP_M, True) for gap in OVERLAP_GAPS for p in planners for s in seeds]
    jobs += [("latency", gap, s, OVERLAP_M, False) for gap in OVERLAP_GAPS for s in seeds]
    started = time.perf_counter()
    with multiprocessing.Pool(os.cpu_count() or 1) as pool:
        runs = pool.map(one_run, jobs, chunksize=1)
    print(f"({len(jobs)} arena runs in {time.perf_counter() - started:.0f} s)\n")
    demo5 = averaged([r for r in runs if r["overlap_m"] == 0], "gap_s", "planner")
    print(f"demo5 protocol, average of {args.seeds} seeds:\n")
    table(demo5, planners, GAPS)
    overlap = averaged([r for r in runs if r["overlap_m"] > 0 and r["routes"]], "gap_s", "planner")
    old = averaged([r for r in runs if not r["routes"]], "gap_s", "planner")
    overlap.update({(gap, "latency, old mapper"): v for (gap, _), v in old.items()})
    print(
        f"\nOverlapping areas ({OVERLAP_M:g} m wider on every side), average of {args.seeds} seeds:\n"
    )
    table(overlap, [*planners, "latency, old mapper"], OVERLAP_GAPS)
    plot(demo5, planners, args.seeds)
    survey(args.seeds)
    replanning()
    if not args.no_simulate:
        against_simulate([1, 2])


if __name__ == "__main__":
    main()
