"""``python -m bench.profile_simulate``: where a simulated task's time goes.

Runs ``simulate`` in this process on a generated grid scenario (``--rows`` x ``--cols`` RVs
in cells of 200 m, ``--vvs`` VVs of ``--tasks`` random point tasks anywhere on the grid, so
that they migrate often) on a fresh SQLite database, under cProfile, and prints: wall time,
tasks a second, the queries per task by statement and table (with their time in the
database), commits per task (transactions and statements outside one, which commit by
themselves), and the functions with the most cumulative time. The
profiler slows the run down (about 1.4 times); the wall time without it is what ``manage.py
simulate`` prints.
"""

from __future__ import annotations

import argparse
import collections
import cProfile
import os
import pstats
import re
import sys
import tempfile
import time
from pathlib import Path
from types import FrameType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
_TABLE = re.compile(r'(?:FROM|INTO|UPDATE)\s+"(\w+)"')


def scenario(rows: int, cols: int, vvs: int, tasks: int) -> dict[str, Any]:
    from vvm_worker.scenario_gen import grid_box, grid_scenario, original_style_program

    program = original_style_program(box=grid_box(rows=rows, cols=cols, cell_m=200), tasks=tasks)
    return grid_scenario(
        rows=rows,
        cols=cols,
        cell_m=200,
        customers=10,
        max_parallel_vvs=vvs,
        vvs=[
            {"name": f"VV {n}", "customer": f"Customer {n % 10 + 1}", "source": program}
            for n in range(vvs)
        ],
        name=f"{vvs} VVs x {tasks} tasks on {rows}x{cols} RVs",
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rows", type=int, default=4)
    parser.add_argument("--cols", type=int, default=4)
    parser.add_argument("--vvs", type=int, default=100)
    parser.add_argument("--tasks", type=int, default=10)
    parser.add_argument("--top", type=int, default=30, help="functions to list")
    parser.add_argument(
        "--sort", default="cumulative", help="order of the functions (cumulative, tottime)"
    )
    parser.add_argument("--top-sites", type=int, default=40, help="query sites to list")
    parser.add_argument("--dump", help="also write the profile to this file (for pstats, snakeviz)")
    parser.add_argument(
        "--sites", action="store_true", help="also list where in the project the queries come from"
    )
    args = parser.parse_args()

    tmp = tempfile.mkdtemp(prefix="cpcc-profile-")
    os.environ.update(
        CPCC_VAR_DIR=tmp,
        CPCC_MEDIA_ROOT=str(Path(tmp) / "media"),
        DJANGO_SETTINGS_MODULE="cpcc_site.settings",
    )
    os.chdir(ROOT)
    import django

    django.setup()
    from django.db import connection

    from vvm_worker.management.commands.simulate import use_fresh_database
    from vvm_worker.scenario import parse_scenario
    from vvm_worker.simulation import Simulation

    use_fresh_database(Path(tmp))
    count: collections.Counter[str] = collections.Counter()
    spent: collections.defaultdict[str, float] = collections.defaultdict(float)
    sites: collections.Counter[str] = collections.Counter()

    def measure(execute: Any, sql: str, params: Any, many: bool, context: Any) -> Any:
        table = _TABLE.search(sql)
        key = f"{sql.split()[0].upper()} {table.group(1) if table else ''}".strip()
        started = time.perf_counter()
        if key.split()[0] in ("INSERT", "UPDATE", "DELETE") and not connection.in_atomic_block:
            count["lone write"] += 1  # a statement outside a transaction commits by itself
        try:
            return execute(sql, params, many, context)
        finally:
            count[key] += 1
            spent[key] += time.perf_counter() - started
            if args.sites:
                sites[f"{key:<32} {_project_frames()}"] += 1

    data = scenario(args.rows, args.cols, args.vvs, args.tasks)
    simulation = Simulation(parse_scenario(data, base_dir=ROOT), seed=1, speed=0, logins=False)
    profile = cProfile.Profile()
    with connection.execute_wrapper(measure):
        started = time.perf_counter()
        profile.enable()
        summary = simulation.run()
        profile.disable()
        wall = time.perf_counter() - started
    tasks = sum(v["tasks_done"] for v in summary["vvs"]) or 1
    queries = sum(n for key, n in count.items() if key != "lone write")
    commits = count["BEGIN"] + count["lone write"]
    print(f"{data['name']}: {wall:.1f} s under the profiler, {tasks} tasks, {tasks / wall:.1f} "
          f"tasks/s, {len(summary['migrations'])} migrations, {simulation.events_run} events")  # fmt: skip
    print(
        f"{queries} statements = {queries / tasks:.1f} a task, {sum(spent.values()):.1f} s in "
        f"the database; commits: {commits / tasks:.1f} a task ({count['BEGIN'] / tasks:.1f} "
        f"transactions, {count['lone write'] / tasks:.1f} statements outside one)"
    )
    print("statements a task, mean time, kind and table:")
    for key, n in [(k, n) for k, n in count.most_common(21) if k != "lone write"]:
        print(f"  {n / tasks:6.2f}  {spent[key] * 1000 / n:6.3f} ms  {key}")
    if args.sites:
        print("statements a task by kind, table and the project's calls that made them:")
        for site, n in sites.most_common(args.top_sites):
            print(f"  {n / tasks:6.2f}  {site}")
    if args.dump:
        profile.dump_stats(args.dump)
    pstats.Stats(profile).sort_stats(args.sort).print_stats(args.top)


def _project_frames(depth: int = 3) -> str:
    """The innermost project functions on the stack (file:function), innermost first."""
    frames: list[str] = []
    frame: FrameType | None = sys._getframe(2)
    while frame is not None and len(frames) < depth:
        name = frame.f_code.co_filename
        if name.startswith(str(ROOT)) and "/.venv/" not in name and "/bench/" not in name:
            frames.append(f"{Path(name).stem}:{frame.f_code.co_name}")
        frame = frame.f_back
    return " < ".join(frames)


if __name__ == "__main__":
    main()
