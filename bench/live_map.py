"""``python -m bench.live_map``: the live map's feed under load.

Starts the web server (daphne, the project's ASGI application) on a fresh SQLite database,
a publisher process that plays RV workers (each RV's state appended to the feed
``--hz`` times a second, as `vvm_worker.hosts.RVHost` does, each carrying a VV of one of the
customers), and ``--clients`` WebSocket clients on ``/ws/map/``: a tenth of them staff (who
see every RV), the rest customers' users (who see the RVs carrying their VVs). It reports:

- frame latency: from a vehicle state's publication (its ``t``) to its receipt by a client,
  p50 / p99 / max over every vehicle in every frame;
- frames lost: gaps in a socket's frame numbers (``seq``);
- updates lost: states a client should have seen (published during the measurement, of a
  vehicle it may see) that never reached it.

Redis: the embedded server by default, ``--redis redis://127.0.0.1:6379/15`` for a real one
(its feed keys are deleted first).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TypedDict

ROOT = Path(__file__).resolve().parents[1]
CUSTOMERS = 10


class Results(TypedDict):
    """What the sockets saw: every vehicle state's latency (s), the frames lost at each gap,
    and per socket the (vehicle, ``t``) pairs it received."""

    latency: list[float]
    lost: list[int]
    seen: list[set[tuple[str | int, float]]]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _setup(n_clients: int) -> list[tuple[str, int | None]]:
    """Users with a session each: (session id, customer id or None for staff)."""
    import django

    django.setup()
    from django.core.management import call_command
    from django.test import Client

    from accounts.models import Customer, User

    call_command("migrate", verbosity=0)
    customers = [Customer.objects.create(name=f"Customer {n}") for n in range(CUSTOMERS)]
    sessions = []
    for n in range(n_clients):
        staff = n % 10 == 0
        customer = None if staff else customers[n % CUSTOMERS]
        user = User.objects.create_user(f"user{n}", password="x", is_staff=staff, customer=customer)
        client = Client()
        client.force_login(user)
        sessions.append(
            (client.cookies["sessionid"].value, None if customer is None else customer.pk)
        )
    return sessions


def _publisher(
    url: str, rvs: int, hz: float, customers: list[int], stop_at: float, log: str
) -> None:
    """RV workers' beacons: every RV's state ``hz`` times a second, evenly spread; ``log``
    gets (RV, customer, t) of every publication."""
    import django

    django.setup()
    from vvm_worker.live import _client_for, publish_vehicle

    client = _client_for(url)
    period = 1.0 / hz
    start = time.time()
    published = []
    n = 0
    while time.time() < stop_at:
        rv = n % rvs
        due = start + (n // rvs) * period + (rv / rvs) * period
        delay = due - time.time()
        if delay > 0:
            time.sleep(delay)
        customer = customers[rv % len(customers)]
        t = time.time()
        published.append((rv, customer, t))
        publish_vehicle(
            {
                "id": rv + 1,
                "name": f"RV {rv + 1}",
                "lat": 48.1 + rv * 1e-4,
                "lng": 12.8 + (n // rvs) * 1e-6,
                "alt": 50.0,
                "phase": "cruise",
                "status": "active",
                "battery": None,
                "vvs": [{"id": f"vv-{rv}", "name": f"VV {rv}", "customer": customer}],
                "route": [[48.1, 12.8], [48.2, 12.9]],
                "t": t,
            },
            client,
        )
        n += 1
    Path(log).write_text(json.dumps(published))


async def _client(url: str, session: str, until: float, results: Results, index: int) -> None:
    import websockets

    latencies, lost_frames, seen = results["latency"], results["lost"], results["seen"]
    async with websockets.connect(
        url,
        # The page's origin, port included: the socket refuses any other.
        additional_headers={
            "Cookie": f"sessionid={session}",
            "Origin": "http" + url.removeprefix("ws").split("/ws/", 1)[0],
        },
        max_size=None,
    ) as ws:
        seq = None
        mine: set[tuple[str | int, float]] = set()
        while time.time() < until:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=max(0.1, until - time.time()))
            except TimeoutError:
                break
            now = time.time()
            frame = json.loads(raw)
            if seq is not None and frame["seq"] != seq + 1:
                lost_frames.append(frame["seq"] - seq - 1)
            seq = frame["seq"]
            if frame["type"] != "frame":
                continue
            for vehicle in frame["vehicles"]:
                latencies.append(now - vehicle["t"])
                mine.add((vehicle.get("name") or vehicle["id"], vehicle["t"]))
        seen[index] = mine


def _measure(
    port: int, sessions: list[tuple[str, int | None]], seconds: float, warmup: float
) -> Results:
    results: Results = {"latency": [], "lost": [], "seen": [set()] * len(sessions)}
    until = time.time() + warmup + seconds

    async def run() -> None:
        await asyncio.gather(
            *(
                _client(f"ws://127.0.0.1:{port}/ws/map/", s, until, results, n)
                for n, (s, _) in enumerate(sessions)
            )
        )

    asyncio.run(run())
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rvs", type=int, default=100)
    parser.add_argument("--hz", type=float, default=2.0)
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--redis", default="", help="redis:// URL (default: embedded)")
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="cpcc-bench-map-"))
    env = {
        **os.environ,
        "DJANGO_SETTINGS_MODULE": "cpcc_site.settings",
        "DATABASE_URL": f"sqlite:///{tmp / 'db.sqlite3'}",
        "CPCC_VAR_DIR": str(tmp),
        "DEBUG": "false",
        "SECRET_KEY": "bench",
        "ALLOWED_HOSTS": "127.0.0.1,localhost",
    }
    embedded = None
    if args.redis:
        env["REDIS_URL"] = args.redis
        feed_url = args.redis
    else:
        from cpcc_site.embedded_redis import EmbeddedRedis

        sock = tmp / "redis.sock"
        embedded = EmbeddedRedis(sock)
        embedded.start()
        env["REDIS_URL"] = feed_url = f"unix://{sock}"
    os.environ.update(env)
    sys.path.insert(0, str(ROOT))
    sessions = _setup(args.clients)
    from missions.events import EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH
    from vvm_worker.live import _client_for

    _client_for(feed_url).delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)

    port = _free_port()
    web = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "daphne",
            "-b",
            "127.0.0.1",
            "-p",
            str(port),
            "cpcc_site.asgi:application",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.time() + 30
        while time.time() < deadline:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                time.sleep(0.1)
        warmup = 3.0
        customers = sorted({c for _, c in sessions if c is not None})
        stop_at = time.time() + warmup + args.seconds + 2
        log = str(tmp / "published.json")
        publisher = multiprocessing.get_context("spawn").Process(
            target=_publisher, args=(feed_url, args.rvs, args.hz, customers, stop_at, log)
        )
        publisher.start()
        started = time.time()
        results = _measure(port, sessions, args.seconds, warmup)
        publisher.join()
    finally:
        web.terminate()
        try:
            web.wait(10)
        except subprocess.TimeoutExpired:
            web.kill()
            web.wait()
        if embedded is not None:
            embedded.stop()

    # Updates a client should have seen: every publication of a vehicle it may see, from
    # after the warm-up until a second before the end (what is still in flight then is not
    # counted as lost).
    published = json.loads(Path(log).read_text())
    window = (started + warmup, started + warmup + args.seconds - 1)
    expected = lost = 0
    for (_, customer), seen in zip(sessions, results["seen"], strict=True):
        want = sum(
            1
            for _, owner, t in published
            if window[0] <= t <= window[1] and customer in (None, owner)
        )
        got = sum(1 for _, t in seen if window[0] <= t <= window[1])
        expected += want
        lost += max(0, want - got)
        if os.environ.get("BENCH_VERBOSE"):
            print("client", "staff" if customer is None else customer, "want", want, "got", got)
    ms = sorted(x * 1000 for x in results["latency"])
    q = statistics.quantiles(ms, n=100)
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
        f"redis: {'embedded' if embedded else args.redis}"
    )
    print(
        f"{args.rvs} RVs at {args.hz:g} Hz, {args.clients} sockets "
        f"({sum(1 for _, c in sessions if c is None)} staff), {args.seconds:g} s"
    )
    print(
        f"frame latency: p50 {statistics.median(ms):.1f} ms  p99 {q[98]:.1f} ms  "
        f"max {ms[-1]:.1f} ms  (n={len(ms)})"
    )
    print(f"frames lost: {sum(results['lost'])}   updates lost: {lost} of {expected}")


if __name__ == "__main__":
    main()
