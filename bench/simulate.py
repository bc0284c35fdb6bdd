"""``python -m bench.simulate``: how ``manage.py simulate`` grows with the fleet and the work.

Runs ``manage.py simulate --speed 0 --json`` (a fresh SQLite database each time, as a user
would) on generated grid scenarios of growing size: ``R`` RVs in cells of 200 m, ``10 R`` VVs of
10 random point tasks anywhere on the grid (so that nearly every task is a migration), every VV
submitted at once. Reports for each size the wall time, tasks a second of wall time (the
command's own report) and the peak resident memory of the process, and checks that every VV
finished. ``--sizes`` picks the fleets (RVs: 10, 100 and, with ``--large``,
1,000: 100,000 tasks, about an hour on a 2-core machine).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
_SPEED = re.compile(r"in ([\d.]+) s of wall time: ([\d,.]+) tasks/s")


def grid_for(rvs: int) -> tuple[int, int]:
    """Rows and columns of a grid of ``rvs`` cells, as square as it divides."""
    rows = int(rvs**0.5)
    while rvs % rows:
        rows -= 1
    return rows, rvs // rows


def scenario(rvs: int, vvs: int, tasks: int) -> dict[str, Any]:
    from vvm_worker.scenario_gen import grid_box, grid_scenario, original_style_program

    rows, cols = grid_for(rvs)
    program = original_style_program(box=grid_box(rows=rows, cols=cols, cell_m=200), tasks=tasks)
    customers = max(1, vvs // 100)
    return grid_scenario(
        rows=rows,
        cols=cols,
        cell_m=200,
        customers=customers,
        max_parallel_vvs=vvs // customers + 1,
        vvs=[
            {
                "name": "VV",
                "customer": f"Customer {c + 1}",
                "source": program,
                "copies": vvs // customers,
            }
            for c in range(customers)
        ],
        name=f"{rvs} RVs, {vvs} VVs x {tasks} tasks",
    )


def run(rvs: int, vvs: int, tasks: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="cpcc-bench-simulate-") as tmp:
        path = Path(tmp) / "scenario.json"
        path.write_text(json.dumps(scenario(rvs, vvs, tasks)))
        env = {
            **os.environ,
            "CPCC_VAR_DIR": tmp,
            "CPCC_MEDIA_ROOT": str(Path(tmp) / "media"),
        }
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        started = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "manage.py", "simulate", str(path), "--speed", "0", "--json"],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - started
        peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if done.returncode != 0:
        raise SystemExit(f"simulate failed:\n{done.stderr[-3000:]}")
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    match = _SPEED.search(done.stderr)
    if match is None:
        raise SystemExit(f"simulate did not report its speed:\n{done.stderr[-2000:]}")
    statuses = {vv["status"] for vv in summary["vvs"]}
    return {
        "rvs": rvs,
        "vvs": len(summary["vvs"]),
        "tasks": sum(vv["tasks_done"] for vv in summary["vvs"]),
        "migrations": len(summary["migrations"]),
        "run_s": float(match.group(1)),
        "rate": float(match.group(2).replace(",", "")),
        "process_s": wall,
        # ru_maxrss of the children is the largest child so far: right when sizes grow.
        "peak_mb": peak_kb / 1024 if peak_kb > before else None,
        "all_finished": statuses == {"finished"},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="*", default=[10, 100], help="RVs per run")
    parser.add_argument("--large", action="store_true", help="also 1,000 RVs, 100,000 tasks")
    parser.add_argument("--tasks", type=int, default=10, help="tasks per VV")
    args = parser.parse_args()
    sizes = [*args.sizes, *([1000] if args.large else [])]
    print(
        f"# {platform.processor() or platform.machine()} · {os.cpu_count()} cores · "
        f"Python {platform.python_version()} · {time.strftime('%Y-%m-%d')}"
    )
    print(
        "| RVs | VVs | tasks | migrations | run | tasks/s | ms a task | peak memory | all finished |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for rvs in sizes:
        r = run(rvs, 10 * rvs, args.tasks)
        peak = f"{r['peak_mb']:,.0f} MB" if r["peak_mb"] else "(below an earlier run)"
        print(
            f"| {r['rvs']:,} | {r['vvs']:,} | {r['tasks']:,} | {r['migrations']:,} | "
            f"{r['run_s']:,.1f} s | {r['rate']:,.1f} | {1000 / r['rate']:.1f} | {peak} | "
            f"{'yes' if r['all_finished'] else 'no'} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
