"""``python -m bench.platform``: the distributed platform's throughput and latencies.

Starts one ground-station worker and one worker per RV (separate processes, as on separate
machines; ``--group N``: one process per N RVs; ``--station-in-group``: the first RV worker
hosts the ground station instead of a worker of its own) on a grid of cells, submits many
original-style VVs with instant flights (time acceleration 0: what is measured is the
software's own limit), waits until every VV has ended and reports how the submission went
and, from the database, how the VVs ran.

The submission, with ``--rest`` (the default): one daphne web process (DEBUG off, the API's
throttles raised far above the load, so that no 429 is measured) and ``--clients`` concurrent
clients, each with one keep-alive connection, POST every VV to ``/api/v1/vvs/`` with their
customer's API token. Reported: the wall time from the first POST to the last 201, requests a
second and each request's latency; any other answer stops the bench with its body.
``--direct`` submits the same VVs in this process instead (``scenario_submit_all``), no HTTP.

- throughput: tasks done per second of wall time, from the first submission (the first POST)
  to the last end (the last VV's ``finished_s``, which the bench looks for every 0.5 s); and
  its two parts: the start phase, until every VV has asked for its first task (the tasks done
  meanwhile), and the tasks a second after it;
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
import http.client
import itertools
import json
import os
import platform
import queue
import secrets
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from bench._live import (
    REQUEST_TIMEOUT_S,
    START_TIMEOUT_S,
    children_of,
    cpu_s,
    fresh_postgres,
    listening_socket,
    pids_of,
)

ROOT = Path(__file__).resolve().parents[1]
# The web process as in production (bench.load does the same), with the API's throttles far
# above the bench's rate: every client comes from 127.0.0.1 and each customer's from one user.
THROTTLE_RATE = "1000000/minute"
WEB_ENV = {
    "DEBUG": "0",
    "ALLOWED_HOSTS": "127.0.0.1",
    "CPCC_HTTPS": "0",
    "CPCC_API_RATE_USER": THROTTLE_RATE,
    "CPCC_API_RATE_ADDRESS": THROTTLE_RATE,
}
TARGET_VVS, TARGET_S = 200, 2.0  # issues 13 and 23: 200 VVs submitted over REST in under 2 s


SPEED_WORK = "10 million additions in a Python loop"
# At a module's level (global names), as docs/benchmarks.md has measured it since 2026-11-30.
_SPEED_CODE = compile("s = 0\nfor i in range(10_000_000):\n    s += i\n", "<speed>", "exec")


def machine_speed_s() -> float:
    """Seconds this process takes for SPEED_WORK: how fast the machine's CPU is right now."""
    started = time.perf_counter()
    exec(_SPEED_CODE, {})  # the bench's own constant code
    return time.perf_counter() - started


def _pcts(values: list[float]) -> str:
    if not values:
        return "no samples"
    ms = sorted(v * 1000 for v in values)
    q = statistics.quantiles(ms, n=100) if len(ms) >= 100 else None
    p90 = q[89] if q else ms[int(0.9 * (len(ms) - 1))]
    p99 = q[98] if q else ms[-1]
    return f"p50 {statistics.median(ms):8.1f} ms   p90 {p90:8.1f} ms   p99 {p99:8.1f} ms   (n={len(ms)})"


@dataclass
class Post:
    """One POST /api/v1/vvs/ and its answer (``status``: the HTTP status, or the exception's
    name when there was none)."""

    sent: float
    done: float
    status: int | str
    body: bytes


def _post(conn: http.client.HTTPConnection, token: str, body: bytes) -> tuple[int | str, bytes]:
    headers = {
        "Authorization": f"Token {token}",
        "Content-Type": "application/json",
        "Accept": "application/json",
    }
    try:
        conn.request("POST", "/api/v1/vvs/", body, headers)
        answer = conn.getresponse()
        return answer.status, answer.read()
    except (OSError, http.client.HTTPException) as exc:
        conn.close()  # the next request opens a new connection
        return type(exc).__name__, str(exc).encode()


def _commits(database: str) -> int | None:
    """Transactions committed in the database so far (PostgreSQL's statistics), or None."""
    if not database.startswith("postgres"):
        return None
    from django.db import connection

    with connection.cursor() as cursor:
        cursor.execute("SELECT pg_stat_clear_snapshot()")
        cursor.execute(
            "SELECT xact_commit FROM pg_stat_database WHERE datname = current_database()"
        )
        return int(cursor.fetchone()[0])


def _idle(
    seconds: float, cpu_by_role: Callable[[], dict[str, float]], rvs: int, database: str
) -> None:
    """What the workers cost with nothing to do: CPU by role and, with PostgreSQL, commits."""
    cpu, commits = cpu_by_role(), _commits(database)
    time.sleep(seconds)
    after, commits_after = cpu_by_role(), _commits(database)
    print(f"idle for {seconds:g} s, before any VV:")
    for role in ("rvworker", "gsworker"):
        share = (after.get(role, 0.0) - cpu.get(role, 0.0)) / seconds
        each = share / (rvs if role == "rvworker" else 1)
        print(f"  {role:<38} {share * 100:6.1f} % of a core   ({each * 100:.2f} % each)")
    if commits is not None and commits_after is not None:
        rate = (commits_after - commits) / seconds
        # The benchmark's own statistics queries commit too: two a snapshot.
        print(
            f"  transactions committed                 {rate:6.1f}/s   ({rate / rvs:.2f}/s an RV)"
        )


def _wait_for_web(port: int, token: str, web: subprocess.Popen[bytes], log: Path) -> None:
    """Until the web process answers a GET with the token, then one POST of a program that
    does not parse: answered 400 with nothing created, it starts V8 in the web process, which
    the first measured POST would pay for otherwise."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=REQUEST_TIMEOUT_S)
    deadline = time.monotonic() + START_TIMEOUT_S
    try:
        while True:
            if web.poll() is not None:
                raise SystemExit(f"the web process exited; see {log}")
            try:
                conn.request("GET", "/api/v1/sensors/", headers={"Authorization": f"Token {token}"})
                answer = conn.getresponse()
                answer.read()
                if answer.status == 200:
                    break
            except (OSError, http.client.HTTPException):
                conn.close()
            if time.monotonic() > deadline:
                raise SystemExit(f"the web process did not answer; see {log}")
            time.sleep(0.2)
        status, body = _post(conn, token, json.dumps({"name": "warm-up", "program": "("}).encode())
        if status != 400:
            raise SystemExit(f"a program that does not parse was answered {status}: {body!r}")
    finally:
        conn.close()


def _post_all(port: int, jobs: list[tuple[str, bytes]], clients: int) -> list[Post]:
    """POST every (token, JSON body) to /api/v1/vvs/ from ``clients`` threads, each with one
    keep-alive connection and sending its next request once the previous one is answered."""
    todo: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    for job in jobs:
        todo.put(job)
    posts: list[Post] = []

    def client() -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=REQUEST_TIMEOUT_S)
        try:
            while True:
                try:
                    token, body = todo.get_nowait()
                except queue.Empty:
                    return
                sent = time.time()
                status, answer = _post(conn, token, body)
                posts.append(Post(sent, time.time(), status, answer))
        finally:
            conn.close()

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return posts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--rvs", type=int, default=10, help="RV workers (a grid of 2 x RVS/2 cells)"
    )
    parser.add_argument(
        "--group", type=int, default=1, help="RVs one rvworker process hosts (1: one each)"
    )
    parser.add_argument(
        "--station-in-group",
        action="store_true",
        help="the first RV worker hosts the ground station too (rvworker --station) instead "
        "of a gsworker of its own",
    )
    parser.add_argument(
        "--bulk",
        type=int,
        default=1,
        help="VVs a POST submits (a JSON list, up to 200; 1: one VV a POST)",
    )
    parser.add_argument("--vvs", type=int, default=200)
    parser.add_argument("--tasks", type=int, default=10, help="tasks per VV")
    parser.add_argument("--cell", type=float, default=200.0, help="cell size, metres")
    parser.add_argument(
        "--database", default="", help="postgres://... (default: a new SQLite file)"
    )
    how = parser.add_mutually_exclusive_group()
    how.add_argument(
        "--rest",
        dest="rest",
        action="store_true",
        default=True,
        help="submit the VVs over REST to one daphne web process (the default)",
    )
    how.add_argument(
        "--direct",
        dest="rest",
        action="store_false",
        help="submit them in this process (scenario_submit_all), without HTTP",
    )
    parser.add_argument(
        "--clients", type=int, default=8, help="concurrent REST clients (keep-alive each)"
    )
    parser.add_argument(
        "--idle-s",
        type=float,
        default=0.0,
        help="first measure the workers idle for this long (CPU; transactions with PostgreSQL)",
    )
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="cpcc-bench-"))
    database = args.database or f"sqlite:///{tmp / 'bench.sqlite3'}"
    if database.startswith("postgres"):
        fresh_postgres(database)
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
    from django.db.models import Max
    from rest_framework.authtoken.models import Token

    from accounts.models import User
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
    from vvm_worker.scenario import parse_scenario, vv_instances
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
    loaded = scenario_apply(scenario=scenario, password=settings.CPCC_SCENARIO_PASSWORD)
    # The same VVs as scenario_submit_all's, each POSTed with its customer's token (the
    # customer's login user is named after its slug).
    tokens = {
        c.slug: Token.objects.get_or_create(user=User.objects.get(username=c.slug))[0].key
        for c in loaded.customers.values()
    }
    jobs = [
        (
            tokens[loaded.customers[spec.customer].slug],
            json.dumps({"name": name, "program": spec.source}).encode(),
        )
        for spec, name in vv_instances(scenario)
    ]
    vv_count = len(jobs)
    if args.bulk > 1:  # each customer's VVs in lists of up to --bulk, one POST each
        by_token: dict[str, list[bytes]] = {}
        for token, body in jobs:
            by_token.setdefault(token, []).append(body)
        jobs = [
            (token, b"[" + b",".join(bodies[i : i + args.bulk]) + b"]")
            for token, bodies in by_token.items()
            for i in range(0, len(bodies), args.bulk)
        ]

    env = {**os.environ, "REDIS_URL": redis_url}
    children: list[subprocess.Popen[bytes]] = []
    role_of: dict[int, str] = {}  # a child's pid: its role
    logs = []
    posts: list[Post] = []
    speed_before = machine_speed_s()

    def start(
        label: str,
        command: list[str],
        extra_env: dict[str, str] | None = None,
        pass_fds: tuple[int, ...] = (),
    ) -> subprocess.Popen[bytes]:
        log = (tmp / f"{label}.log".replace(" ", "_")).open("wb")
        logs.append(log)
        child = subprocess.Popen(
            [sys.executable, *command],
            cwd=ROOT,
            env={**env, **(extra_env or {})},
            stdout=log,
            stderr=subprocess.STDOUT,
            pass_fds=pass_fds,
        )
        children.append(child)
        role_of[child.pid] = command[1] if command[0] == "manage.py" else "web (daphne)"
        return child

    # The workers as in production: DEBUG off (Django then keeps no statement log).
    worker_env = {"DEBUG": "0", "CPCC_HTTPS": "0", "SECRET_KEY": secrets.token_urlsafe(50)}
    servers = {"PostgreSQL": ("postgres", ""), "Redis": ("redis-server", "")}
    cpu: dict[str, float] = {}

    def cpu_by_role() -> dict[str, float]:
        """CPU seconds so far by role, a worker's with its planner process's (a server's
        processes that have exited, such as a connection's backend, no longer count)."""
        spent = {role: sum(cpu_s(p) for p in pids_of(*what)) for role, what in servers.items()}
        for child in children:
            role = role_of[child.pid]
            own = [child.pid, *children_of(child.pid)]  # an RV worker's planner process too
            spent[role] = spent.get(role, 0.0) + sum(cpu_s(pid) for pid in own)
        spent["this benchmark"] = time.process_time()
        return spent

    try:
        stations = list(loaded.ground_stations)
        if args.station_in_group:
            if len(stations) != 1:
                raise SystemExit("--station-in-group needs a scenario of one ground station")
        else:
            for name in stations:
                start(f"gsworker-{name}", ["manage.py", "gsworker", name], extra_env=worker_env)
        rv_names = list(loaded.vehicles)
        for first in range(0, len(rv_names), args.group):
            group = rv_names[first : first + args.group]
            station_flag = ["--station", stations[0]] if args.station_in_group and not first else []
            start(
                f"rvworker-{group[0]}",
                ["manage.py", "rvworker", *group, *station_flag],
                extra_env=worker_env,
            )
        workers = len(children)
        if args.rest:
            listener = listening_socket(0)
            port = listener.getsockname()[1]
            with listener:
                web = start(
                    "web",
                    ["-m", "daphne", "--fd", str(listener.fileno()), "cpcc_site.asgi:application"],
                    extra_env={**WEB_ENV, "SECRET_KEY": secrets.token_urlsafe(50)},
                    pass_fds=(listener.fileno(),),
                )
        # Let every worker announce itself, and the web process answer, before the clock starts.
        deadline = time.monotonic() + START_TIMEOUT_S
        while sum(1 for p in tmp.glob("*worker-*.log") if b"worker " in p.read_bytes()) < workers:
            if time.monotonic() > deadline:
                raise SystemExit("the workers did not start; see " + str(tmp))
            time.sleep(0.2)
        if args.rest:
            _wait_for_web(port, next(iter(tokens.values())), web, tmp / "web.log")
        if args.idle_s > 0:
            _idle(args.idle_s, cpu_by_role, len(loaded.vehicles), database)
        cpu_at_start = cpu_by_role()
        if args.rest:
            posts = _post_all(port, jobs, args.clients)
            refused = [p for p in posts if p.status != 201]
            if refused:
                counts = Counter(str(p.status) for p in refused)
                raise SystemExit(
                    f"{len(refused)} of {len(posts)} POSTs not answered 201 "
                    f"({', '.join(f'{n} x {st}' for st, n in counts.most_common())}); the first: "
                    f"{refused[0].status} {refused[0].body.decode(errors='replace')}"
                )
            started = min(p.sent for p in posts)
            total = vv_count
        else:
            started = time.time()
            total = len(scenario_submit_all(scenario=scenario, loaded=loaded, vvm=platform_vvm()))
        while VirtualVehicle.objects.filter(status__in=ENDED_STATUSES).count() < total:
            time.sleep(0.5)
            if any(p.poll() is not None for p in children):
                raise SystemExit("a worker or the web process died; see " + str(tmp))
        seen = time.time()
        # The last end as the platform recorded it (the same clock: the workers' wall time),
        # not the look that saw it up to half a second later.
        last = VirtualVehicle.objects.aggregate(last=Max("finished_s"))["last"]
        ended = seen if last is None else min(seen, last)
        cpu = {role: s - cpu_at_start.get(role, 0.0) for role, s in cpu_by_role().items()}
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

    speed_after = machine_speed_s()
    finished = VirtualVehicle.objects.filter(status=VVStatus.FINISHED).count()
    done = Task.objects.filter(status=TaskStatus.DONE).count()
    request: list[float] = []
    same: list[float] = []
    other: list[float] = []
    first_asked: list[float] = []  # each VV's first task, asked for at
    for vv_id in VirtualVehicle.objects.values_list("pk", flat=True):
        tasks = list(
            Task.objects.filter(vv_id=vv_id)
            .order_by("q")
            .values("vehicle_id", "done_s", "assigned_s", "requested_s")
        )
        if tasks:
            first_asked.append(min(t["requested_s"] for t in tasks))
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
    print(
        f"machine speed: {SPEED_WORK} in {speed_before:.2f} s before the run, "
        f"{speed_after:.2f} s after (a VM's speed drifts: compare runs of similar speed)"
    )
    workers_rv = -(-args.rvs // args.group)
    station = (
        "the GS in the first RV worker (rvworker --station)"
        if args.station_in_group
        else "1 GS worker"
    )
    print(
        f"{args.rvs} RVs in {workers_rv} RV worker(s) + {station}, {total} VVs x {args.tasks} "
        "tasks, instant flights"
    )
    if args.rest:
        print(
            f"submitted over REST: {args.clients} clients (keep-alive) POST /api/v1/vvs/ "
            f"({args.bulk} VV(s) a request) to one "
            f"daphne process, DEBUG off, API throttles raised to {THROTTLE_RATE} (no 429s)"
        )
        wall = max(p.done for p in posts) - started
        target = f"floor: {TARGET_VVS} in under {TARGET_S:g} s"
        if total >= TARGET_VVS:
            target += ", met" if wall < TARGET_S else ", not met"
        print(
            f"{f'{total} VVs submitted over REST':<41}{wall:8.2f} s   first POST -> last 201 "
            f"({target})"
        )
        print(
            f"REST submissions                         {len(posts) / wall:8.1f} requests/s "
            f"({total / wall:.1f} VVs/s, {args.bulk} a request)"
        )
        print(f"POST /api/v1/vvs/                        {_pcts([p.done - p.sent for p in posts])}")
    else:
        print("submitted directly (scenario_submit_all in the bench's process, no HTTP)")
    print(
        f"VVs finished {finished}/{total}, tasks done {done} in {ended - started:.2f} s "
        f"(the last VV's end; the bench saw it {seen - ended:.2f} s later)"
    )
    print(f"throughput                               {done / (ended - started):8.1f} tasks/s")
    starts_end = max(first_asked, default=ended)
    during = Task.objects.filter(status=TaskStatus.DONE, done_s__lte=starts_end).count()
    print(
        f"  start phase (to the last VV's first task) {starts_end - started:6.2f} s, "
        f"{during} tasks done; after it {(done - during) / max(ended - starts_end, 1e-9):.1f} "
        "tasks/s"
    )
    print(f"completion -> the VV's next request      {_pcts(request)}")
    print(f"completion -> next task, same RV         {_pcts(same)}")
    print(f"completion -> next task, another RV      {_pcts(other)}")
    print(f"migration RV -> RV to task taken on      {_pcts(migration)}")
    spent = sum(cpu.values())
    print(f"CPU from the first submission to the last end: {spent:.1f} s, "
          f"{spent * 1000 / max(done, 1):.1f} ms a task:")  # fmt: skip
    for role, seconds in sorted(cpu.items(), key=lambda item: -item[1]):
        print(f"  {role:<38} {seconds:8.1f} s   {seconds * 1000 / max(done, 1):6.1f} ms a task")


if __name__ == "__main__":
    main()
