"""``python -m bench.idle`` (``make bench-idle``): what an RV worker costs with nothing to do.

Starts one ground-station worker and one RV worker hosting ``--rvs`` simulated RVs (a grid of
2 x RVS/2 cells, ``manage.py rvworker NAME [NAME ...]``), as in production (DEBUG off), on a
fresh database with no VV, lets them settle, and measures the RV worker's CPU time (user +
system, all its threads and its planner process's, from /proc) over ``--seconds``: the CPU a hosted RV costs when idle
(issue 23: floor < 0.1 % of a core per RV, goal < 0.02 %). Also reported: how often the
worker's threads wake up (context switches), and the GS worker's CPU for comparison.
``--per-process`` starts one RV worker per RV instead (the shape before issue 23). The
workers are stopped with SIGTERM at the end, which must end each with exit status 0.

Use ``--database postgres://...`` for PostgreSQL (the database is dropped and created anew)
and ``REDIS_URL`` for a real Redis; by default a fresh SQLite file and the embedded Redis.
"""

from __future__ import annotations

import argparse
import os
import platform
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

from bench._live import children_of

ROOT = Path(__file__).resolve().parents[1]
TICK = os.sysconf("SC_CLK_TCK")
START_TIMEOUT_S = 120.0
FLOOR_PCT, GOAL_PCT = 0.1, 0.02  # CPU of a core per idle hosted RV (issue 23)


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def switches(pid: int) -> int:
    """Context switches of all the process's threads so far (each wake-up of a thread that
    slept is one voluntary switch)."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            status = (task / "status").read_text()
        except OSError:  # a thread that just ended
            continue
        for line in status.splitlines():
            if line.startswith(("voluntary_ctxt_switches", "nonvoluntary_ctxt_switches")):
                total += int(line.split()[1])
    return total


def resident_mb(pid: int) -> float:
    """Resident memory (VmRSS) of a process, MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def _fresh_postgres(url: str) -> None:
    import psycopg

    base, _, name = url.rpartition("/")
    admin = base.replace("postgres://", "postgresql://", 1) + "/postgres"
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.execute(f'CREATE DATABASE "{name}"')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rvs", type=int, default=10, help="simulated RVs (default 10)")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured for this long")
    parser.add_argument(
        "--settle", type=float, default=10.0, help="seconds after the start before measuring"
    )
    parser.add_argument(
        "--per-process", action="store_true", help="one RV worker per RV (the old shape)"
    )
    parser.add_argument(
        "--database", default="", help="postgres://... (default: a new SQLite file)"
    )
    args = parser.parse_args()
    if args.rvs < 1:
        raise SystemExit("--rvs must be at least 1")

    tmp = Path(tempfile.mkdtemp(prefix="cpcc-bench-idle-"))
    database = args.database or f"sqlite:///{tmp / 'bench.sqlite3'}"
    if database.startswith("postgres"):
        _fresh_postgres(database)
    os.environ.update(
        {
            "DATABASE_URL": database,
            "CPCC_VAR_DIR": str(tmp),
            "DJANGO_SETTINGS_MODULE": "cpcc_site.settings",
        }
    )
    import django

    django.setup()
    from django.conf import settings
    from django.core.management import call_command

    from cpcc_site.embedded_redis import EmbeddedRedis
    from vvm_worker.scenario import parse_scenario
    from vvm_worker.scenario_gen import grid_scenario
    from vvm_worker.services.scenarios import scenario_apply

    call_command("migrate", verbosity=0)
    redis = None if settings.REDIS_URL else EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET).start()
    redis_url = settings.REDIS_URL or f"unix://{settings.EMBEDDED_REDIS_SOCKET}"
    rows = 1 if args.rvs == 1 else 2
    cols = -(-args.rvs // rows)
    data = grid_scenario(rows=rows, cols=cols, cell_m=200.0)
    data["vehicles"] = data["vehicles"][: args.rvs]
    loaded = scenario_apply(scenario=parse_scenario(data, base_dir=ROOT), logins=False)
    names = list(loaded.vehicles)

    env = {
        **os.environ,
        "REDIS_URL": redis_url,
        "DEBUG": "0",
        "CPCC_HTTPS": "0",
        "SECRET_KEY": secrets.token_urlsafe(50),
    }
    children: dict[str, subprocess.Popen[bytes]] = {}
    logs: dict[str, Path] = {}

    def start(label: str, *command: str) -> None:
        log = tmp / f"{command[0]}-{len(children)}.log"
        logs[label] = log
        children[label] = subprocess.Popen(
            [sys.executable, "manage.py", *command],
            cwd=ROOT,
            env=env,
            stdout=log.open("wb"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    try:
        for gs in loaded.ground_stations:
            start(f"gsworker {gs}", "gsworker", gs)
        groups = [[name] for name in names] if args.per_process else [names]
        for group in groups:
            start(f"rvworker {', '.join(group)}", "rvworker", *group)
        deadline = time.monotonic() + START_TIMEOUT_S
        for label, log in logs.items():
            while f"{label}:".encode() not in log.read_bytes():
                if children[label].poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"{label} did not start:\n{log.read_text()[-3000:]}")
                time.sleep(0.2)
        time.sleep(args.settle)
        rv_pids = [p.pid for label, p in children.items() if label.startswith("rvworker")]
        rv_pids += [pid for worker in list(rv_pids) for pid in children_of(worker)]  # planners
        gs_pids = [p.pid for label, p in children.items() if label.startswith("gsworker")]
        before = [cpu_s(pid) for pid in rv_pids], [cpu_s(pid) for pid in gs_pids]
        woken = sum(switches(pid) for pid in rv_pids)
        started = time.monotonic()
        time.sleep(args.seconds)
        elapsed = time.monotonic() - started
        after = [cpu_s(pid) for pid in rv_pids], [cpu_s(pid) for pid in gs_pids]
        woken = sum(switches(pid) for pid in rv_pids) - woken
        resident = sum(resident_mb(pid) for pid in rv_pids)
    finally:
        statuses = {}
        for child in children.values():
            if child.poll() is None:
                os.killpg(child.pid, signal.SIGTERM)
        for label, child in children.items():
            try:
                statuses[label] = child.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(child.pid, signal.SIGKILL)
                statuses[label] = child.wait()
        if redis is not None:
            redis.stop()

    rv_pct = 100 * (sum(after[0]) - sum(before[0])) / elapsed
    gs_pct = 100 * (sum(after[1]) - sum(before[1])) / elapsed
    each = rv_pct / len(names)
    verdict = "goal met" if each < GOAL_PCT else "floor met" if each < FLOOR_PCT else "ABOVE FLOOR"
    shape = (
        f"{len(names)} RV workers of one RV each"
        if args.per_process
        else f"one RV worker hosting {len(names)} RVs"
    )
    print(
        f"idle RV workers, {date.today()}, {platform.node()}, {os.cpu_count()} cores, "
        f"{'PostgreSQL' if database.startswith('postgres') else 'SQLite'}, "
        f"{elapsed:.0f} s measured after {args.settle:g} s"
    )
    print(f"  {shape}: {rv_pct:.3f} % of a core")
    print(
        f"  per hosted RV: {each:.4f} % of a core "
        f"(floor < {FLOOR_PCT} %, goal < {GOAL_PCT} %: {verdict})"
    )
    print(f"  wake-ups of the RV workers' threads: {woken / elapsed:.1f}/s")
    print(f"  resident memory of the RV workers: {resident:.0f} MB")
    print(f"  the GS worker: {gs_pct:.3f} % of a core")
    bad = {label: status for label, status in statuses.items() if status != 0}
    if bad:
        raise SystemExit(f"workers that did not exit 0 on SIGTERM: {bad} (logs in {tmp})")


if __name__ == "__main__":
    main()
