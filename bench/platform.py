"""``python -m bench.platform``: the distributed platform's throughput and latencies.

Starts one ground-station worker and one worker per RV (separate processes, as on separate
machines) on a grid of cells, submits many original-style VVs with instant flights (time
acceleration 0: what is measured is the software's own limit), waits until every VV has ended
and reports, from the database:

- throughput: tasks done per second of wall time, from the first submission to the last end;
- completion to the VV's next request: from a task's answer to the program's next blocking call
  (the RV that took the reading resumes the VV itself: a step, no message);
- completion to next task on the same RV: from a task's answer to the VV's next task being
  taken on by the RV it is on (a VV step in the RV's worker, no message);
- completion to next task on another RV: the same when the next task is elsewhere, so the VV
  migrates: route, Celery message through Redis, the new RV's worker takes it up;
- migration latency: from a migration's record to the new RV taking the VV's task on.

Use ``--database postgres://...`` for PostgreSQL (the database is dropped and created anew)
and ``REDIS_URL`` for a real Redis; by default a fresh SQLite file and the embedded Redis.
"""

from __future__ import annotations

import argparse
import itertools
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _fresh_postgres(url: str) -> None:
    import psycopg

    base, _, name = url.rpartition("/")
    admin = base.replace("postgres://", "postgresql://", 1) + "/postgres"
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.execute(f'CREATE DATABASE "{name}"')


def _pcts(values: list[float]) -> str:
    if not values:
        return "no samples"
    ms = sorted(v * 1000 for v in values)
    q = statistics.quantiles(ms, n=100) if len(ms) >= 100 else None
    p90 = q[89] if q else ms[int(0.9 * (len(ms) - 1))]
    p99 = q[98] if q else ms[-1]
    return f"p50 {statistics.median(ms):8.1f} ms   p90 {p90:8.1f} ms   p99 {p99:8.1f} ms   (n={len(ms)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--rvs", type=int, default=10, help="RV workers (a grid of 2 x RVS/2 cells)"
    )
    parser.add_argument("--vvs", type=int, default=200)
    parser.add_argument("--tasks", type=int, default=10, help="tasks per VV")
    parser.add_argument("--cell", type=float, default=200.0, help="cell size, metres")
    parser.add_argument(
        "--database", default="", help="postgres://... (default: a new SQLite file)"
    )
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="cpcc-bench-"))
    database = args.database or f"sqlite:///{tmp / 'bench.sqlite3'}"
    if database.startswith("postgres"):
        _fresh_postgres(database)
    os.environ.update(
        {
            "DATABASE_URL": database,
            "CPCC_VAR_DIR": str(tmp),
            "CPCC_SIM_SPEED": "0",
            "DJANGO_SETTINGS_MODULE": "cpcc_site.settings",
            "CPCC_SCENARIO_PASSWORD": "bench-password",
        }
    )
    import django

    django.setup()
    from django.conf import settings
    from django.core.management import call_command

    from cpcc_site.embedded_redis import EmbeddedRedis
    from missions.models import (
        ENDED_STATUSES,
        Migration,
        Task,
        TaskStatus,
        VirtualVehicle,
        VVStatus,
    )
    from vvm_worker.platform import platform_vvm
    from vvm_worker.scenario import parse_scenario
    from vvm_worker.scenario_gen import grid_box, grid_scenario, original_style_program
    from vvm_worker.services.scenarios import scenario_apply, scenario_submit_all

    call_command("migrate", verbosity=0)
    redis = None if settings.REDIS_URL else EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET).start()
    redis_url = settings.REDIS_URL or f"unix://{settings.EMBEDDED_REDIS_SOCKET}"
    rows, cols = 2, max(1, args.rvs // 2)
    box = grid_box(rows=rows, cols=cols, cell_m=args.cell)
    customers = max(1, args.vvs // 20)
    data = grid_scenario(
        rows=rows, cols=cols, cell_m=args.cell, customers=customers, max_parallel_vvs=args.vvs
    )
    source = original_style_program(box=box, tasks=args.tasks)
    per = -(-args.vvs // customers)
    data["vvs"] = [
        {"customer": f"Customer {c + 1}", "name": "bench", "source": source, "copies": per}
        for c in range(customers)
    ]
    scenario = parse_scenario(data, base_dir=ROOT)
    loaded = scenario_apply(scenario=scenario)

    env = {**os.environ, "REDIS_URL": redis_url}
    children = []
    logs = []
    try:
        for kind, names in (("gsworker", loaded.ground_stations), ("rvworker", loaded.vehicles)):
            for name in names:
                log = (tmp / f"{kind}-{name}.log".replace(" ", "_")).open("wb")
                logs.append(log)
                children.append(
                    subprocess.Popen(
                        [sys.executable, "manage.py", kind, name],
                        cwd=ROOT,
                        env=env,
                        stdout=log,
                        stderr=subprocess.STDOUT,
                    )
                )
        # Let every worker announce itself before the clock starts.
        deadline = time.monotonic() + 120
        while sum(1 for p in tmp.glob("*.log") if b"worker " in p.read_bytes()) < len(children):
            if time.monotonic() > deadline:
                raise SystemExit("the workers did not start; see " + str(tmp))
            time.sleep(0.2)
        started = time.time()
        vvs = scenario_submit_all(scenario=scenario, loaded=loaded, vvm=platform_vvm())
        total = len(vvs)
        while VirtualVehicle.objects.filter(status__in=ENDED_STATUSES).count() < total:
            time.sleep(0.5)
            if any(p.poll() is not None for p in children):
                raise SystemExit("a worker died; see " + str(tmp))
        ended = time.time()
    finally:
        for p in children:
            p.terminate()
        for p in children:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
        for log in logs:
            log.close()
        if redis is not None:
            redis.stop()

    finished = VirtualVehicle.objects.filter(status=VVStatus.FINISHED).count()
    done = Task.objects.filter(status=TaskStatus.DONE).count()
    request: list[float] = []
    same: list[float] = []
    other: list[float] = []
    for vv_id in VirtualVehicle.objects.values_list("pk", flat=True):
        tasks = list(
            Task.objects.filter(vv_id=vv_id)
            .order_by("q")
            .values("vehicle_id", "done_s", "assigned_s", "requested_s")
        )
        for a, b in itertools.pairwise(tasks):
            if a["done_s"] is None or b["assigned_s"] is None:
                continue
            request.append(b["requested_s"] - a["done_s"])
            next_rv = same if a["vehicle_id"] == b["vehicle_id"] else other
            next_rv.append(b["assigned_s"] - a["done_s"])
    migration: list[float] = []
    for m in Migration.objects.filter(from_kind="rv", to_kind="rv").values(
        "vv_id", "at_s", "to_name"
    ):
        nxt = (
            Task.objects.filter(
                vv_id=m["vv_id"], vehicle__name=m["to_name"], assigned_s__gte=m["at_s"]
            )
            .order_by("assigned_s")
            .values_list("assigned_s", flat=True)
            .first()
        )
        if nxt is not None:
            migration.append(nxt - m["at_s"])

    machine = platform.processor() or platform.machine()
    engine = "PostgreSQL" if database.startswith("postgres") else "SQLite"
    print(
        f"# {machine} · {os.cpu_count()} cores · {engine} · Redis {'external' if settings.REDIS_URL else 'embedded'}"
    )
    print(f"{args.rvs} RV workers + 1 GS worker, {total} VVs x {args.tasks} tasks, instant flights")
    print(f"VVs finished {finished}/{total}, tasks done {done} in {ended - started:.1f} s")
    print(f"throughput                               {done / (ended - started):8.1f} tasks/s")
    print(f"completion -> the VV's next request      {_pcts(request)}")
    print(f"completion -> next task, same RV         {_pcts(same)}")
    print(f"completion -> next task, another RV      {_pcts(other)}")
    print(f"migration RV -> RV to task taken on      {_pcts(migration)}")


if __name__ == "__main__":
    sys.exit(main())
