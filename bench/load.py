"""``python -m bench.load`` (``make bench-load``): the REST API and the live map under load.

Starts the platform as a provider runs it in production, every part a process of its own on
this machine: a fresh PostgreSQL database (``--database``, dropped and created anew) and a
Redis database of the bench's own (``--redis``, flushed), ``migrate`` and ``collectstatic``,
the scenario's fleet (``--scenario``, the paper's Figure 3 by default: two RVs and a ground
station) with ``--customers`` customers instead of the scenario's, each with ``--history``
earlier VVs (so that its list is a full page, as on a platform in use), one worker per RV and
per ground station, and the web tier as in production: gunicorn's sync workers answer HTTP
(``--web`` of them, with cpcc_site/gunicorn_conf.py) and one daphne the map's sockets, as a
proxy in front routes ``/ws/`` (``--http daphne``: ``--web`` daphne processes answer both,
sharing one listening socket, ``daphne --fd``, as supervisord or systemd socket activation
runs them), with ``DEBUG=0``, plain HTTP (``CPCC_HTTPS=0``), instant flights (``CPCC_SIM_SPEED=0``) and
the API's throttles raised far above the load (``CPCC_API_RATE_USER`` and
``CPCC_API_RATE_ADDRESS``: every client comes from 127.0.0.1, each customer's from one user).
``--settings`` tries a settings change without editing cpcc_site: a module on PYTHONPATH that
imports ``cpcc_site.settings`` and overrides.

Then ``--clients`` REST clients (asyncio and aiohttp, one keep-alive connection each, the
customers' API tokens) act like customers at a fixed total rate (``--rate`` requests a second,
each client on its own schedule): submit a small VV of 1-3 point tasks in the fleet's area
(at most ``--vv-rate`` submissions a second over all clients, what the fleet can serve
alongside), poll it, list their VVs now and then, and once it has ended fetch its storage, log
and results.zip; a client without a VV of its own in flight reads its recent VVs and its list
like a dashboard would. At the same time ``--subscribers`` WebSocket clients (a fifth of them
staff, the rest customers' users, logged in with a session) hold the live map
(``/ws/map/``) open, in a process of their own.

Measured over ``--duration`` seconds after ``--warmup``:

- requests a second, latency p50 / p95 / p99 / max overall and per endpoint (from sending a
  request to its whole answer), and from its scheduled time (which also counts a client's
  wait behind a slow answer: the honest figure at a fixed rate);
- errors by status: anything but 201 for a submission and 200 otherwise (429 included);
- the live map: frames and changes a second delivered to all subscribers, the latency from
  a change's platform time (a task requested or done, ``requested_s`` / ``done_s``, stamped
  by the worker inside the transaction that publishes it) and from a vehicle state's ``t`` to
  its receipt, frames lost;
- where the CPU went: the web, worker and subscriber processes, the load generator, the
  PostgreSQL backends of the bench's database, and the whole machine; new database
  connections a second (``pg_stat_database.sessions``).

Target: 200 requests a second with p99 under 100 ms on a 2-core machine. Everything (server,
workers, PostgreSQL, Redis, clients) shares the machine's cores. Every process the bench
starts is stopped when it ends, fails or is interrupted. Prints a markdown table for
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime as dt
import json
import multiprocessing
import os
import platform
import random
import secrets
import shutil
import signal
import socket
import statistics
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict
from urllib.parse import urlparse

from bench._live import (
    REQUEST_TIMEOUT_S,
    START_TIMEOUT_S,
    Children,
    cpu_s,
    fresh_postgres,
    fresh_redis,
    listening_socket,
    pids_of,
)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENARIO = ROOT / "examples" / "scenarios" / "paper-fig3.json"
DEFAULT_DATABASE = "postgres://postgres@127.0.0.1:5432/cpcc_bench_load"
DEFAULT_REDIS = "redis://127.0.0.1:6379/14"
VAR_DIR = ROOT / "var" / "bench-load"  # kept between runs: collectstatic copies only changes
ENDED = {"finished", "failed", "killed", "cancelled"}
PREFERRED_SENSORS = ("GPS", "CO2", "Thermometer")
TARGET_RATE, TARGET_P99_MS = 200.0, 100.0

# What a client without a VV in flight does on its turn, with weights: a customer's script or
# dashboard reading its recent VVs.
IDLE_MIX = (("detail", 5), ("list", 3), ("storage", 1), ("log", 1))
# A client polling its VV lists its VVs instead on every this many turns.
LIST_EVERY = 4
# What a client fetches, one a turn, once its VV has ended.
RESULTS = ("storage/", "log/", "results.zip")


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


# --- CPU accounting -------------------------------------------------------------------------


def _with_descendants(pids: list[int]) -> list[int]:
    """The processes and all their children (gunicorn's workers under its master)."""
    children: dict[int, list[int]] = defaultdict(list)
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError, IndexError):
                ppid = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
                children[ppid].append(int(proc.name))
    found, todo = [], list(pids)
    while todo:
        pid = todo.pop()
        found.append(pid)
        todo.extend(children.get(pid, ()))
    return found


def _machine_ticks() -> tuple[int, int]:
    """(busy, total) jiffies of all cores since boot."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + values[4]  # idle + iowait
    return sum(values) - idle, sum(values)


def _cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def _memory_gb() -> int:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return round(int(line.split()[1]) / 1024 / 1024)
    return 0


# --- the platform -------------------------------------------------------------------------


@dataclass
class Setup:
    tokens: list[tuple[str, str]]  # (customer slug, API token)
    sessions: list[tuple[str, int | None]]  # (session id, customer id or None for staff)
    areas: list[dict[str, Any]]  # where tasks may go: ring, altitudes
    sensors: list[str]
    workers: list[tuple[str, str]]  # (command, host name)


def _load_platform(args: argparse.Namespace) -> Setup:
    """Migrate, collect static files, load the fleet and the customers with their tokens and
    the map subscribers' sessions (in this process, through the platform's services)."""
    import django

    django.setup()
    from django.core.management import call_command
    from django.db import connections
    from django.test import Client
    from rest_framework.authtoken.models import Token

    from accounts.models import User
    from vvm_worker.platform import platform_vvm
    from vvm_worker.scenario import parse_scenario
    from vvm_worker.services import user_set_login
    from vvm_worker.services.admission import vv_submit
    from vvm_worker.services.scenarios import scenario_apply
    from vvm_worker.services.vvs import vv_cancel

    call_command("migrate", verbosity=0, interactive=False)
    call_command("collectstatic", verbosity=0, interactive=False)
    path = Path(args.scenario)
    data = json.loads(path.read_text())
    data["customers"] = [
        {"name": f"Bench Customer {n + 1}", "max_parallel_vvs": args.max_parallel_vvs}
        for n in range(args.customers)
    ]
    data["vvs"] = []
    data.pop("events", None)
    scenario = parse_scenario(data, base_dir=path.parent, file=str(path))
    loaded = scenario_apply(scenario=scenario)
    # Earlier VVs, so that a customer's list is a full page as on a platform in use: queued
    # without being admitted and cancelled at once (no worker runs yet).
    vvm = platform_vvm()
    for customer in loaded.customers.values():
        for n in range(args.history):
            vv = vv_submit(
                customer=customer, name=f"earlier {n}", program=HISTORY, vvm=vvm, admit=False
            )
            vv_cancel(vv_id=vv.pk, vvm=vvm)
    tokens = []
    for username, _ in loaded.logins:
        token, _ = Token.objects.get_or_create(user=User.objects.get(username=username))
        tokens.append((username, token.key))
    staff = user_set_login(username="bench-staff", password=secrets.token_urlsafe(16), staff=True)
    customer_users = list(User.objects.filter(customer__isnull=False).order_by("username"))
    sessions = []
    for n in range(args.subscribers):
        user = staff if n % 5 == 0 else customer_users[n % len(customer_users)]
        client = Client()
        client.force_login(user)
        # customer_id: Django's foreign-key column, which django-stubs types only through its
        # mypy plugin (not enabled here).
        sessions.append((client.cookies["sessionid"].value, user.customer_id))  # type: ignore[attr-defined]
    common = set.intersection(*(set(v.sensors) for v in scenario.vehicles))
    sensors = [s for s in PREFERRED_SENSORS if s in common] or sorted(
        s for s in common if "camera" not in s.lower()
    )[:1]
    if not sensors:
        raise SystemExit("the scenario's vehicles have no sensor but cameras in common")
    areas = [
        {
            "ring": [list(p) for p in v.area],
            "low": max(v.min_altitude_m, 5.0),
            "high": max(min(v.max_altitude_m, 60.0), max(v.min_altitude_m, 5.0)),
        }
        for v in scenario.vehicles
    ]
    workers = [("gsworker", name) for name in loaded.ground_stations] + [
        ("rvworker", name) for name in loaded.vehicles
    ]
    connections.close_all()
    return Setup(
        tokens=tokens,
        sessions=sessions,
        areas=areas,
        sensors=sensors,
        workers=workers,
    )


# --- the customers' programs ----------------------------------------------------------------

HISTORY = "VV.log('an earlier VV');\n"

PROGRAM = """\
// bench.load: %(n)d point task(s) in the fleet's area, readings kept in storage.
var sensors = %(sensors)s.map(function (name) { return VV.sensor.get(name); });
var points = %(points)s;
for (var n = 0; n < points.length; ++n) {
  var p = points[n];
  VV.task.execute(
    {type: 'point', position: new VV.types.LatLngAlt(p[0], p[1], p[2]), tolerance: 2, sensors: sensors},
    function (data) {
      for (var k = 0; k < data.length; ++k) VV.storage.store('p' + n + '.' + k, data[k]);
    }
  );
}
VV.log('done:', VV.storage.list().length, 'readings');
"""


def _program(rng: random.Random, areas: list[dict[str, Any]], sensors: list[str]) -> str:
    """A VV of 1-3 point tasks, each in the area of a random RV (so some VVs migrate)."""
    from shapely.geometry import Point, Polygon

    points = []
    for _ in range(rng.randint(1, 3)):
        area = rng.choice(areas)
        polygon = Polygon(area["ring"])
        inner = polygon.buffer(-0.1 * min(polygon.bounds[2] - polygon.bounds[0], 0.001))
        south, west, north, east = inner.bounds
        while True:
            lat, lng = rng.uniform(south, north), rng.uniform(west, east)
            if inner.contains(Point(lat, lng)):
                break
        alt = rng.uniform(area["low"], area["high"])
        points.append([round(lat, 7), round(lng, 7), round(alt, 1)])
    return PROGRAM % {
        "n": len(points),
        "sensors": json.dumps(sensors),
        "points": json.dumps(points),
    }


# --- the REST clients ---------------------------------------------------------------------


@dataclass
class Sample:
    endpoint: str
    status: str  # the HTTP status, or the exception's name
    sched: float
    sent: float
    done: float


@dataclass
class Run:
    """What every client records and shares."""

    base: str
    rate: float
    vv_rate: float
    started: float
    window: tuple[float, float]
    samples: list[Sample] = field(default_factory=list)
    first_submissions: int = 0  # each client starts with a VV of its own, in the warm-up
    next_submission: float = 0.0
    submitted: dict[str, float] = field(default_factory=dict)  # VV id -> submission sent
    ended: dict[str, tuple[str, float]] = field(default_factory=dict)  # id -> (status, seen)

    def may_submit(self, now: float) -> bool:
        """The fleet's share: at most ``vv_rate`` submissions a second over all clients."""
        if self.first_submissions > 0:
            self.first_submissions -= 1
            return True
        if self.vv_rate <= 0 or now < self.next_submission:
            return False
        self.next_submission = max(self.next_submission, now - 1.0 / self.vv_rate)
        self.next_submission += 1.0 / self.vv_rate
        return True


EXPECTED = {"POST /vvs/": "201"}


async def _get_vv(http: Any, run: Run, vv: str, suffix: str, turn: float) -> tuple[str, Any]:
    """GET one of a VV's resources (``suffix``: "", "storage/", "log/", "results.zip")."""
    return await _request(
        http, run, f"GET /vvs/{{id}}/{suffix}", "GET", f"/api/v1/vvs/{vv}/{suffix}", turn
    )


async def _request(
    http: Any, run: Run, endpoint: str, method: str, path: str, sched: float, **kw: Any
) -> tuple[str, Any]:
    import aiohttp

    sent = time.time()
    body: Any = None
    try:
        async with http.request(method, run.base + path, **kw) as response:
            status = str(response.status)
            if response.content_type == "application/json":
                body = await response.json()
            else:
                body = await response.read()
    except (aiohttp.ClientError, TimeoutError) as exc:
        status = type(exc).__name__
    run.samples.append(Sample(endpoint, status, sched, sent, time.time()))
    return status, body


async def _customer(
    run: Run, token: str, index: int, period: float, stop: float, programs: Iterator[str]
) -> None:
    """One customer's client: a request on each turn of its schedule (every ``period``
    seconds, or at once when the previous answer came late)."""
    import aiohttp

    rng = random.Random(index)
    headers = {"Authorization": f"Token {token}", "Accept": "application/json"}
    mine: str | None = None  # the VV in flight
    polls = 0
    fetch: list[tuple[str, str]] = []  # results still to fetch of the VV that ended
    recent: list[str] = []
    turn = run.started + rng.uniform(0, period)
    async with aiohttp.ClientSession(
        headers=headers,
        connector=aiohttp.TCPConnector(limit=1),
        timeout=aiohttp.ClientTimeout(total=REQUEST_TIMEOUT_S),
    ) as http:
        # A client behind its schedule sends at once, but none after the window.
        while turn < stop and time.time() < stop:
            delay = turn - time.time()
            if delay > 0:
                await asyncio.sleep(delay)
            if fetch:
                vv, suffix = fetch.pop(0)
                await _get_vv(http, run, vv, suffix, turn)
            elif mine is not None:
                polls += 1
                if polls % LIST_EVERY == 0:
                    await _request(http, run, "GET /vvs/", "GET", "/api/v1/vvs/", turn)
                else:
                    status, body = await _request(
                        http, run, "GET /vvs/{id}/", "GET", f"/api/v1/vvs/{mine}/", turn
                    )
                    if status == "200" and body["status"] in ENDED:
                        run.ended[mine] = (body["status"], time.time())
                        fetch = [(mine, suffix) for suffix in RESULTS]
                        mine = None
            elif run.may_submit(time.time()):
                sent = time.time()
                status, body = await _request(
                    http,
                    run,
                    "POST /vvs/",
                    "POST",
                    "/api/v1/vvs/",
                    turn,
                    json={"name": f"load {index}", "program": next(programs)},
                )
                if status == "201":
                    mine, polls = body["id"], 0
                    run.submitted[mine] = sent
                    recent = [mine, *recent[:9]]
            else:
                kind = rng.choices([k for k, _ in IDLE_MIX], [w for _, w in IDLE_MIX])[0]
                if kind == "list" or not recent:
                    await _request(http, run, "GET /vvs/", "GET", "/api/v1/vvs/", turn)
                else:
                    vv = rng.choice(recent)
                    suffix = {"detail": "", "storage": "storage/", "log": "log/"}[kind]
                    await _get_vv(http, run, vv, suffix, turn)
            turn += period


async def _clients(
    run: Run,
    tokens: list[tuple[str, str]],
    n: int,
    stop: float,
    programs: Iterator[str],
    progress: Callable[[Run], None] | None,
) -> None:
    period = n / run.rate
    tasks = [
        asyncio.create_task(_customer(run, tokens[i % len(tokens)][1], i, period, stop, programs))
        for i in range(n)
    ]
    while not all(t.done() for t in tasks):
        await asyncio.sleep(0.5)
        if progress is not None:
            progress(run)
    for t in tasks:
        t.result()


# --- the live map's subscribers (a process of their own) ----------------------------------


def _subscribers(
    port: int, sessions: list[tuple[str, int | None]], shared: Any, ready: Any, out: str
) -> None:
    """Open ``sessions`` map sockets, set ``ready`` once each has been answered, hold them
    open until the window (``shared``: start and end, set by the bench once ``ready``) ends,
    and write what they received in the window."""
    import websockets

    def window() -> tuple[float, float]:
        start, end = shared[0], shared[1]
        return (start, end) if end else (float("inf"), float("inf"))

    answered = 0

    def handshake_done() -> None:
        nonlocal answered
        answered += 1
        if answered == len(sessions):
            ready.set()

    result: dict[str, Any] = {
        "frames": 0,
        "events": Counter(),
        "change_latency": [],
        "vehicle_latency": [],
        "lost": 0,
        "connected": 0,
        "failed": [],
    }

    async def one(session: str) -> None:
        shaken = False
        try:
            async with websockets.connect(
                f"ws://127.0.0.1:{port}/ws/map/",
                # The page's origin, port included: the socket refuses any other.
                additional_headers={
                    "Cookie": f"sessionid={session}",
                    "Origin": f"http://127.0.0.1:{port}",
                },
                max_size=None,
                open_timeout=30,
            ) as ws:
                result["connected"] += 1
                shaken = True
                handshake_done()
                seq = None
                while time.time() < window()[1]:
                    try:
                        raw = await asyncio.wait_for(ws.recv(), timeout=1.0)
                    except TimeoutError:
                        continue
                    now = time.time()
                    frame = json.loads(raw)
                    start, end = window()
                    counted = start <= now <= end
                    if seq is not None and frame["seq"] != seq + 1 and counted:
                        result["lost"] += frame["seq"] - seq - 1
                    seq = frame["seq"]
                    if frame["type"] != "frame" or not counted:
                        continue
                    result["frames"] += 1
                    for event in frame["events"]:
                        result["events"][event["kind"]] += 1
                        # A task's request and its answer carry the platform's time
                        # (the worker's clock, inside the transaction that announces them).
                        if event["kind"] == "task" and event["status"] in ("open", "done"):
                            at = event["requested_s" if event["status"] == "open" else "done_s"]
                            result["change_latency"].append(now - at)
                    for vehicle in frame["vehicles"]:
                        result["vehicle_latency"].append(now - vehicle["t"])
        except Exception as exc:
            result["failed"].append(f"{type(exc).__name__}: {exc}")
            if not shaken:
                handshake_done()

    async def main() -> None:
        await asyncio.gather(*(one(s) for s, _ in sessions))

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
    Path(out).write_text(json.dumps(result))


# --- figures ------------------------------------------------------------------------------


def _pct(ms: list[float], p: float) -> float:
    """The p-th percentile (nearest rank) of sorted values."""
    if not ms:
        return float("nan")
    return ms[min(len(ms) - 1, max(0, round(p / 100 * len(ms) + 0.5) - 1))]


def _fmt_ms(v: float) -> str:
    return "-" if v != v else f"{v:,.1f} ms"


def _endpoint_rows(samples: list[Sample], seconds: float) -> list[list[str]]:
    by: dict[str, list[Sample]] = defaultdict(list)
    for s in samples:
        by[s.endpoint].append(s)
    order = sorted(by, key=lambda e: -len(by[e]))
    rows = []
    for name, group in [*((e, by[e]) for e in order), ("all", samples)]:
        ms = sorted((s.done - s.sent) * 1000 for s in group)
        sched = sorted((s.done - s.sched) * 1000 for s in group)
        errors = Counter(s.status for s in group if s.status != EXPECTED.get(s.endpoint, "200"))
        rows.append(
            [
                f"`{name}`" if name != "all" else "**all**",
                f"{len(group):,}",
                f"{len(group) / seconds:,.1f}/s",
                _fmt_ms(statistics.median(ms) if ms else float("nan")),
                _fmt_ms(_pct(ms, 95)),
                _fmt_ms(_pct(ms, 99)),
                _fmt_ms(ms[-1] if ms else float("nan")),
                _fmt_ms(_pct(sched, 99)),
                ", ".join(f"{n} x {st}" for st, n in errors.most_common()) or "0",
            ]
        )
    return rows


def _markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


# --- main ---------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=60.0, help="seconds measured")
    parser.add_argument("--warmup", type=float, default=10.0, help="seconds before measuring")
    parser.add_argument("--rate", type=float, default=TARGET_RATE, help="requests a second")
    parser.add_argument("--clients", type=int, default=50, help="REST clients")
    parser.add_argument("--customers", type=int, default=10)
    parser.add_argument("--max-parallel-vvs", type=int, default=5, help="quota per customer")
    parser.add_argument(
        "--vv-rate", type=float, default=1.0, help="VV submissions a second, over all clients"
    )
    parser.add_argument(
        "--history",
        type=int,
        default=50,
        help="earlier VVs per customer (cancelled), so that the list is a full page (50)",
    )
    parser.add_argument("--subscribers", type=int, default=20, help="live map sockets")
    parser.add_argument(
        "--web",
        type=int,
        default=0,
        help="web processes: gunicorn's workers (default: cpcc_site/gunicorn_conf.py's, two "
        "a core), or daphne processes (default 2)",
    )
    parser.add_argument(
        "--http",
        choices=("gunicorn", "daphne"),
        default="gunicorn",
        help="who answers HTTP: gunicorn's sync workers (WSGI) with one daphne for the "
        "sockets, as in production (cpcc_site/gunicorn_conf.py), or daphne alone (ASGI, "
        "HTTP and the map's sockets)",
    )
    parser.add_argument("--scenario", default=str(DEFAULT_SCENARIO), help="the fleet")
    parser.add_argument("--speed", type=float, default=0.0, help="CPCC_SIM_SPEED (0: instant)")
    parser.add_argument("--database", default=DEFAULT_DATABASE, help="dropped and created anew")
    parser.add_argument("--redis", default=DEFAULT_REDIS, help="a Redis database, flushed")
    parser.add_argument(
        "--settings",
        default="cpcc_site.settings",
        help="the Django settings module of every process (to try a change: a module on "
        "PYTHONPATH that imports cpcc_site.settings and overrides)",
    )
    args = parser.parse_args()
    if args.web <= 0:  # production's number of gunicorn workers, or two daphne processes
        from cpcc_site import gunicorn_conf

        args.web = gunicorn_conf.workers if args.http == "gunicorn" else 2

    from rich.console import Console
    from rich.table import Table

    console = Console(stderr=True)
    signal.signal(signal.SIGTERM, _interrupt)
    VAR_DIR.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(VAR_DIR / "media", ignore_errors=True)
    logs = VAR_DIR / "logs"
    shutil.rmtree(logs, ignore_errors=True)
    logs.mkdir()
    # Production-like settings; the throttles (per web process) raised well above the load,
    # as every client shares one address and each customer's clients one user.
    env = {
        **os.environ,
        "DJANGO_SETTINGS_MODULE": args.settings,
        "DATABASE_URL": args.database,
        "REDIS_URL": args.redis,
        "CPCC_VAR_DIR": str(VAR_DIR),
        "DEBUG": "0",
        "SECRET_KEY": secrets.token_urlsafe(50),
        "ALLOWED_HOSTS": "127.0.0.1,localhost",
        "CPCC_HTTPS": "0",
        "CPCC_SIM_SPEED": f"{args.speed:g}",
        "CPCC_API_RATE_USER": "1000000/minute",
        "CPCC_API_RATE_ADDRESS": "1000000/minute",
        "CPCC_LOG_LEVEL": "WARNING",
    }
    os.environ.update(env)
    sys.path.insert(0, str(ROOT))

    from bench.live_map import _free_port

    children = Children(env, logs)
    listener: socket.socket | None = None
    subscribers = None
    try:
        with console.status("fresh database and Redis, migrate, collectstatic, the fleet"):
            fresh_postgres(args.database)
            fresh_redis(args.redis)
            setup = _load_platform(args)
        with console.status(f"starting {len(setup.workers)} workers and {args.web} web processes"):
            for command, name in setup.workers:
                children.start(f"{command} {name}", ["manage.py", command, name])
            port = ws_port = _free_port()
            if args.http == "gunicorn":
                # HTTP to gunicorn's sync workers (WSGI), the map's sockets to one daphne, as
                # a proxy in front would route /ws/.
                children.start(
                    "web",
                    [
                        "-m",
                        "gunicorn",
                        "-c",
                        "python:cpcc_site.gunicorn_conf",
                        "--workers",
                        str(args.web),
                        "--bind",
                        f"127.0.0.1:{port}",
                        "cpcc_site.wsgi:application",
                    ],
                )
                ws_port = _free_port()
                children.start(
                    "ws", ["-m", "daphne", "-p", str(ws_port), "cpcc_site.asgi:application"]
                )
            else:
                listener = listening_socket(port)
                for n in range(args.web):
                    children.start(
                        f"web {n + 1}",
                        [
                            "-m",
                            "daphne",
                            "--fd",
                            str(listener.fileno()),
                            "cpcc_site.asgi:application",
                        ],
                        pass_fds=(listener.fileno(),),
                    )
                listener.close()
                listener = None
            for answering in sorted({port, ws_port}):
                _wait_until_ready(children, setup, answering)
        console.print(
            f"platform up: {len(setup.workers)} workers, {args.web} {args.http} processes on "
            f"http://127.0.0.1:{port}/, logs in {logs}"
        )

        # The map's subscribers connect first (a browser keeps its map open), then the clients
        # start.
        context = multiprocessing.get_context("spawn")
        shared, ready = context.Array("d", 2), context.Event()
        out = str(logs / "subscribers.json")
        subscribers = context.Process(
            target=_subscribers, args=(ws_port, setup.sessions, shared, ready, out)
        )
        subscribers.start()
        if not ready.wait(timeout=60):
            raise SystemExit("the map's sockets were not answered within 60 s")
        started = time.time() + 0.5
        window = (started + args.warmup, started + args.warmup + args.duration)
        shared[0], shared[1] = window
        run = Run(
            base=f"http://127.0.0.1:{port}",
            rate=args.rate,
            vv_rate=args.vv_rate,
            started=started,
            window=window,
            first_submissions=args.clients,
        )
        figures = _measure(args, run, setup, children, subscribers.pid, console)
        subscribers.join(timeout=30)
        children.check()
    except KeyboardInterrupt:
        console.print("interrupted: stopping everything")
        raise SystemExit(130) from None
    finally:
        if subscribers is not None and subscribers.is_alive():
            subscribers.terminate()
            subscribers.join(timeout=10)
        if listener is not None:
            listener.close()
        children.stop()

    subs = json.loads(Path(out).read_text()) if Path(out).exists() else None
    _report(args, run, setup, figures, subs, console, Table)


def _wait_until_ready(children: Children, setup: Setup, port: int) -> None:
    """Every worker has announced itself and every web process answers."""
    import urllib.request

    deadline = time.monotonic() + START_TIMEOUT_S
    workers = [f"{c} {n}" for c, n in setup.workers]
    while any(f"{label}:" not in children.log(label) for label in workers):
        children.check()
        if time.monotonic() > deadline:
            raise SystemExit(f"the workers did not start; see {children.logs}")
        time.sleep(0.2)
    request = urllib.request.Request(
        f"http://127.0.0.1:{port}/api/v1/sensors/",
        headers={"Authorization": f"Token {setup.tokens[0][1]}"},
    )
    while True:
        children.check()
        # One process answering is enough: the others accept on the same socket once they
        # are up, within the warm-up.
        with contextlib.suppress(OSError), urllib.request.urlopen(request, timeout=5) as answer:
            if answer.status == 200:
                return
        if time.monotonic() > deadline:
            raise SystemExit(f"the web server did not answer; see {children.logs}")
        time.sleep(0.2)


class Snapshot(TypedDict):
    """The counters at one edge of the measurement window."""

    t: float
    cpu: dict[str, float]  # CPU seconds so far by role
    self: float  # this process's user + system CPU seconds
    pg: dict[int, float]  # CPU seconds so far of each backend of the bench's database
    machine: tuple[int, int]  # (busy, total) jiffies of all cores
    sessions: int  # database connections made so far
    backends: int  # connections to the bench's database now


@dataclass
class Figures:
    seconds: float  # between the two snapshots of the counters (about the window)
    cpu: dict[str, float]  # CPU seconds in the window by role
    machine_busy: float  # fraction of all cores
    db_sessions: int  # new database connections in the window
    db_backends: int  # connections to the bench's database at the window's end


def _measure(
    args: argparse.Namespace,
    run: Run,
    setup: Setup,
    children: Children,
    subscribers_pid: int | None,
    console: Any,
) -> Figures:
    """Run the clients; take the CPU and database counters at the window's edges."""
    import psycopg
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    base, _, name = args.database.rpartition("/")
    admin = base.replace("postgres://", "postgresql://", 1) + "/postgres"
    pg = psycopg.connect(admin, autocommit=True)

    def pg_counters() -> tuple[int, list[int]]:
        sessions = pg.execute(
            "SELECT sessions FROM pg_stat_database WHERE datname = %s", (name,)
        ).fetchone()
        pids = pg.execute("SELECT pid FROM pg_stat_activity WHERE datname = %s", (name,)).fetchall()
        return int(sessions[0] if sessions else 0), [int(p) for (p,) in pids]

    redis_port = str(urlparse(args.redis).port or 6379)
    web = "web (daphne)" if args.http == "daphne" else "web (gunicorn)"
    roles: dict[str, Callable[[], list[int]]] = {
        web: lambda: _with_descendants(children.pids("web")),
        "Redis server": lambda: pids_of("redis-server", f":{redis_port}"),
        "RV workers": lambda: children.pids("rvworker"),
        "GS worker": lambda: children.pids("gsworker"),
        "map subscribers (bench)": lambda: [subscribers_pid] if subscribers_pid else [],
    }
    if args.http == "gunicorn":
        roles["map sockets (daphne)"] = lambda: children.pids("ws")
    edges: list[Snapshot] = []

    def snapshot() -> None:
        sessions, backends = pg_counters()
        edges.append(
            {
                "t": time.time(),
                "cpu": {role: sum(cpu_s(p) for p in pids()) for role, pids in roles.items()},
                "self": sum(os.times()[:2]),
                "pg": {p: cpu_s(p) for p in backends},
                "machine": _machine_ticks(),
                "sessions": sessions,
                "backends": len(backends),
            }
        )

    rng = random.Random(1)

    def programs() -> Iterator[str]:
        while True:
            yield _program(rng, setup.areas, setup.sensors)

    stop = run.window[1]
    total = stop - run.started
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[status]}"),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task("warm-up", total=total, status="")

        def progress(r: Run) -> None:
            now = time.time()
            if len(edges) == 0 and now >= r.window[0]:
                snapshot()
            if len(edges) == 1 and now >= r.window[1]:
                snapshot()  # the requests still under way are the window's last
            children.check()
            recent = [s for s in r.samples if s.sent >= now - 5]
            errors = sum(1 for s in recent if s.status != EXPECTED.get(s.endpoint, "200"))
            ms = sorted((s.done - s.sent) * 1000 for s in recent)
            bar.update(
                task,
                completed=min(total, now - r.started),
                description="measuring" if now >= r.window[0] else "warm-up",
                status=f"{len(recent) / 5:.0f} req/s, p99 {_fmt_ms(_pct(ms, 99))}, "
                f"{errors} errors (last 5 s); VVs {len(r.submitted)} submitted, "
                f"{len(r.ended)} ended",
            )

        asyncio.run(_clients(run, setup.tokens, args.clients, stop, programs(), progress))
    if len(edges) == 1:
        snapshot()
    pg.close()
    if len(edges) < 2:
        raise SystemExit("the run ended before its window")
    first, last = edges[0], edges[1]
    cpu = {role: last["cpu"][role] - first["cpu"][role] for role in roles}
    # Backends that came and went within the window are missed (with persistent connections
    # there are none; without, "everything else" has them).
    cpu["PostgreSQL (bench database)"] = sum(
        used - first["pg"].get(p, 0.0) for p, used in last["pg"].items()
    )
    cpu["REST clients (bench)"] = last["self"] - first["self"]
    busy = (last["machine"][0] - first["machine"][0]) / max(
        1, last["machine"][1] - first["machine"][1]
    )
    return Figures(
        seconds=last["t"] - first["t"],
        cpu=cpu,
        machine_busy=busy,
        db_sessions=last["sessions"] - first["sessions"],
        db_backends=last["backends"],
    )


def _report(
    args: argparse.Namespace,
    run: Run,
    setup: Setup,
    figures: Figures,
    subs: dict[str, Any] | None,
    console: Any,
    table_class: Any,
) -> None:
    import daphne

    w0, w1 = run.window
    seconds = w1 - w0
    samples = [s for s in run.samples if w0 <= s.sent < w1]
    rows = _endpoint_rows(samples, seconds)
    header = [
        "endpoint",
        "requests",
        "rate",
        "p50",
        "p95",
        "p99",
        "max",
        "p99 from schedule",
        "errors",
    ]
    table = table_class(title=f"REST API, {seconds:g} s after a {args.warmup:g} s warm-up")
    for h in header:
        table.add_column(h, justify="left" if h in ("endpoint", "errors") else "right")
    for r in rows:
        table.add_row(*(c.replace("`", "").replace("**", "") for c in r))
    console.print(table)
    # How the run went over time, warm-up included: a backlog the clients built (lateness
    # behind their schedule) and how long it took to clear.
    step = 5.0
    console.print(f"over time ({step:g} s steps from the clients' start; the window starts at "
                  f"{w0 - run.started:.0f} s): requests/s, p99 latency, max lateness behind schedule")  # fmt: skip
    by_step: dict[int, list[Sample]] = defaultdict(list)
    for s in run.samples:
        by_step[int((s.sent - run.started) // step)].append(s)
    for k in sorted(by_step):
        group = by_step[k]
        lat = sorted((s.done - s.sent) * 1000 for s in group)
        late = max((s.sent - s.sched) * 1000 for s in group)
        posts = sorted((s.done - s.sent) * 1000 for s in group if s.endpoint == "POST /vvs/")
        console.print(
            f"  {k * step:5.0f} s  {len(group) / step:6.1f}/s  p99 {_pct(lat, 99):7.1f} ms  "
            f"late {late:8.1f} ms  POSTs {len(posts)}, slowest {max(posts, default=0):7.1f} ms"
        )

    ms = sorted((s.done - s.sent) * 1000 for s in samples)
    rate = len(samples) / seconds
    p99 = _pct(ms, 99)
    verdict = "met" if rate >= 0.98 * TARGET_RATE and p99 < TARGET_P99_MS else "missed"
    ended = [st for vv, (st, _) in run.ended.items() if w0 <= run.submitted.get(vv, 0) < w1]
    turnaround = sorted(
        (t - run.submitted[vv]) * 1000
        for vv, (st, t) in run.ended.items()
        if st == "finished" and vv in run.submitted
    )

    cores = os.cpu_count() or 1
    web = "web (daphne)" if args.http == "daphne" else "web (gunicorn)"
    per_request = 1000 * figures.cpu[web] / max(1, len(samples))
    cpu_rows = [
        [role, f"{s:,.1f} s", f"{100 * s / figures.seconds:.0f} %"]
        for role, s in sorted(figures.cpu.items(), key=lambda kv: -kv[1])
    ]
    others = figures.machine_busy * figures.seconds * cores - sum(figures.cpu.values())
    if others / figures.seconds > 0.15:
        console.print(
            f"[yellow]the machine was not quiet: other processes used "
            f"{100 * others / figures.seconds:.0f} % of a core during the window[/yellow]"
        )
    cpu_rows.append(
        [
            "everything else on the machine",
            f"{max(0.0, others):,.1f} s",
            f"{max(0.0, 100 * others / figures.seconds):.0f} %",
        ]
    )
    cpu_rows.append(
        [
            "**the whole machine**",
            f"{figures.machine_busy * figures.seconds * cores:,.1f} s",
            f"{100 * figures.machine_busy * cores:.0f} % (of {100 * cores} %)",
        ]
    )

    map_rows: list[list[str]] = []
    if subs is not None:
        change = sorted(v * 1000 for v in subs["change_latency"])
        vehicle = sorted(v * 1000 for v in subs["vehicle_latency"])
        events = sum(subs["events"].values())
        map_rows = [
            [
                f"{subs['connected']} of {len(setup.sessions)}",
                f"{subs['frames'] / seconds:,.1f}/s",
                f"{events / seconds:,.1f}/s",
                f"{_fmt_ms(_pct(change, 50))} / {_fmt_ms(_pct(change, 99))} / "
                f"{_fmt_ms(change[-1] if change else float('nan'))} (n={len(change):,})",
                f"{_fmt_ms(_pct(vehicle, 50))} / {_fmt_ms(_pct(vehicle, 99))} (n={len(vehicle):,})",
                str(subs["lost"]),
            ]
        ]
        for failure in subs["failed"][:5]:
            console.print(f"[red]map socket failed:[/red] {failure}")

    today = dt.date.today().isoformat()
    py = platform.python_version()
    print()
    print(
        f"## {today} · the REST API and the live map under load · {_cpu_model()}, "
        f"{os.cpu_count()} cores, {_memory_gb()} GB, Python {py}, daphne {daphne.__version__}"
    )
    print()
    print(
        f"`make bench-load` (`python -m bench.load {' '.join(sys.argv[1:])}`".rstrip()
        + f"): {len(setup.workers)} workers ({Path(args.scenario).name}), "
        + (
            f"{args.web} daphne processes on one socket"
            if args.http == "daphne"
            else f"gunicorn with {args.web} sync workers (WSGI) and one daphne for the sockets"
        )
        + f", PostgreSQL and Redis on 127.0.0.1, DEBUG off, CPCC_SIM_SPEED={args.speed:g}; "
        f"{args.clients} REST clients of {args.customers} customers (each with "
        f"{args.history} earlier VVs) at {args.rate:g} requests/s in all, "
        f"{args.subscribers} live map sockets. "
        f"Target: {TARGET_RATE:g} requests/s with p99 under {TARGET_P99_MS:g} ms: **{verdict}** "
        f"({rate:,.1f} requests/s, p99 {_fmt_ms(p99)})."
    )
    print()
    print(_markdown(header, rows))
    print()
    print(
        f"VVs: {len(ended)} submitted in the window ended "
        f"({', '.join(f'{n} {st}' for st, n in Counter(ended).most_common()) or 'none'}); "
        f"submission to the client seeing it finished p50 {_fmt_ms(_pct(turnaround, 50))}, "
        f"p95 {_fmt_ms(_pct(turnaround, 95))}. Web processes: {per_request:.1f} ms of CPU "
        f"per request. Database: {figures.db_sessions} new connections in {seconds:g} s, "
        f"{figures.db_backends} open at the end."
    )
    if map_rows:
        print()
        print(
            _markdown(
                [
                    "map sockets",
                    "frames delivered",
                    "changes delivered",
                    "change -> socket p50 / p99 / max",
                    "vehicle state -> socket p50 / p99",
                    "frames lost",
                ],
                map_rows,
            )
        )
    print()
    print(_markdown(["CPU in the window", "CPU time", "of one core"], cpu_rows))


if __name__ == "__main__":
    main()
