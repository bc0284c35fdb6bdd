"""``python -m bench.submit_burst`` (``make bench-burst``): many customers submitting at once.

What issue 20 asked: 200 submissions from 16 concurrent clients to one daphne (the web server
as in production: DEBUG off, the machine's PostgreSQL and Redis), every one answered 201 (or
429 if a throttle says so, never a dropped connection), the server alive after each burst,
``--rounds`` bursts in a row (20 by default); then the server stopped with SIGTERM while
clients still submit, which must end it with exit status 0 within a bounded time.

A fresh PostgreSQL database (``--database``, dropped and created anew) and a Redis database of
its own (``--redis``, flushed); four customers with an API token each, whose tokens the clients
take by turns; no worker runs (the VVs stay queued: this measures the web tier). Each client's
programs differ, so no syntax check is answered from a cache, and every fifth has a syntax
error (400 with its line). Prints a line per burst (answers by status, wall time, latency p50 /
p99) and what the stop took. Also measures a syntax check in this process: in the warm
checking isolate of the V8 thread, and in a new isolate as before.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench._live import Children, fresh_postgres, fresh_redis, listening_socket
from bench.load import _pct

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATABASE = "postgres://postgres@127.0.0.1:5432/cpcc_bench_burst"
DEFAULT_REDIS = "redis://127.0.0.1:6379/13"
PORT = 8791

PROGRAM = """
var co2 = VV.sensor.get('CO2');
var n = {n};
VV.task.execute({{type: 'point', position: new VV.types.LatLngAlt(48.11, 12.86, 50),
                  tolerance: 2, sensors: [co2]}}, function (d) {{ VV.storage.store('n', n); }});
"""
BROKEN = "var n = {n};\nvar = ;\n"


def _body(n: int) -> dict[str, str]:
    return {"name": f"Burst {n}", "program": (BROKEN if n % 5 == 0 else PROGRAM).format(n=n)}


def _setup(database: str) -> list[str]:
    """Migrate and make four customers with a token each (in this process)."""
    os.environ["DATABASE_URL"] = database
    import django

    django.setup()
    from django.core.management import call_command
    from django.db import connections
    from rest_framework.authtoken.models import Token

    from accounts.models import Customer, User

    call_command("migrate", verbosity=0, interactive=False)
    call_command("collectstatic", verbosity=0, interactive=False)
    tokens = []
    for c in "ABCD":
        # No worker admits them: every VV stays queued, far beyond the default queue quota.
        customer = Customer.objects.create(
            name=f"Burst Customer {c}", max_parallel_vvs=5, max_queued_vvs=1_000_000
        )
        user = User.objects.create_user(username=f"burst-{c.lower()}", customer=customer)
        tokens.append(Token.objects.create(user=user).key)
    connections.close_all()
    return tokens


def _burst(
    url: str, tokens: list[str], clients: int, count: int, offset: int
) -> list[tuple[int, int | str, float]]:
    import requests

    def client(c: int) -> list[tuple[int, int | str, float]]:
        api = requests.Session()
        api.headers["Authorization"] = f"Token {tokens[c % len(tokens)]}"
        out: list[tuple[int, int | str, float]] = []
        for n in range(offset + c, offset + count, clients):
            started = time.perf_counter()
            try:
                status: int | str = api.post(
                    f"{url}/api/v1/vvs/", json=_body(n), timeout=60
                ).status_code
            except requests.RequestException as exc:
                status = type(exc).__name__
            out.append((n, status, time.perf_counter() - started))
            if isinstance(status, str):  # the server is gone (stopped)
                break
        return out

    with ThreadPoolExecutor(clients) as pool:
        return [a for answers in pool.map(client, range(clients)) for a in answers]


def _check_costs() -> tuple[float, float]:
    """A syntax check's cost in ms: warm (this process's checking isolate), and in a new
    isolate as before issue 20 (median of 200 each, distinct programs)."""
    from vvm_worker.runtime import check_syntax, v8

    warm = []
    for n in range(220):
        started = time.perf_counter()
        check_syntax(PROGRAM.format(n=10_000 + n))
        warm.append(time.perf_counter() - started)
    cold = []
    for n in range(220):
        started = time.perf_counter()
        isolate = v8.new_isolate()
        with contextlib.suppress(v8.JSEvalException):  # the throw in front
            isolate.eval("throw 0;" + PROGRAM.format(n=20_000 + n), timeout_s=5)
        isolate.close()
        cold.append(time.perf_counter() - started)
    return statistics.median(warm[20:]) * 1000, statistics.median(cold[20:]) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--clients", type=int, default=16)
    parser.add_argument("--submissions", type=int, default=200, help="per round")
    parser.add_argument("--database", default=DEFAULT_DATABASE, help="dropped and created anew")
    parser.add_argument("--redis", default=DEFAULT_REDIS, help="a Redis database, flushed")
    args = parser.parse_args()
    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "cpcc_site.settings")
    var_dir = Path(tempfile.mkdtemp(prefix="cpcc-burst-"))
    env = {
        **os.environ,
        "DATABASE_URL": args.database,
        "REDIS_URL": args.redis,
        "DEBUG": "0",
        "SECRET_KEY": "bench-only-" + "x" * 50,
        "ALLOWED_HOSTS": "127.0.0.1",
        "CPCC_HTTPS": "0",
        "CPCC_VAR_DIR": str(var_dir),
        "PYTHONFAULTHANDLER": "1",
        # Every client comes from 127.0.0.1: the address throttle (2,400 a minute) would
        # answer 429 from the 13th burst on, and the bench would measure the throttle.
        "CPCC_API_RATE_USER": "100000/minute",
        "CPCC_API_RATE_ADDRESS": "100000/minute",
    }
    os.environ.update({k: env[k] for k in ("DEBUG", "SECRET_KEY", "ALLOWED_HOSTS", "CPCC_HTTPS")})
    os.environ["CPCC_VAR_DIR"] = str(var_dir)
    fresh_postgres(args.database)
    fresh_redis(args.redis)
    tokens = _setup(args.database)
    warm_ms, cold_ms = _check_costs()
    print(f"syntax check: {warm_ms:.2f} ms warm (V8 thread), {cold_ms:.2f} ms in a new isolate")

    sock = listening_socket(PORT)
    children = Children(env, var_dir)
    children.start(
        "web",
        ["-m", "daphne", "--fd", str(sock.fileno()), "cpcc_site.asgi:application"],
        pass_fds=(sock.fileno(),),
    )
    sock.close()  # daphne's now: once it stops, a connection is refused, not left waiting
    url = f"http://127.0.0.1:{PORT}"
    import requests

    deadline = time.monotonic() + 60
    while True:
        children.check()
        try:
            requests.get(f"{url}/accounts/login/", timeout=2)
            break
        except requests.RequestException:
            if time.monotonic() > deadline:
                raise SystemExit("the web server did not answer") from None
            time.sleep(0.2)
    failures = 0
    try:
        for round_ in range(args.rounds):
            started = time.perf_counter()
            answers = _burst(url, tokens, args.clients, args.submissions, round_ * 10_000)
            wall = time.perf_counter() - started
            counts = collections.Counter(status for _, status, _ in answers)
            wrong = [
                (n, s)
                for n, s, _ in answers
                if s != (400 if n % 5 == 0 else 201) and not (s == 429 and n % 5)
            ]
            alive = requests.get(f"{url}/accounts/login/", timeout=10).status_code == 200
            failures += bool(wrong) or not alive
            ms = sorted(t * 1000 for _, _, t in answers)
            print(
                f"burst {round_ + 1:2d}: {dict(sorted(counts.items(), key=str))} in {wall:.2f} s"
                f" ({len(answers) / wall:.0f}/s), p50 {_pct(ms, 50):.0f} ms,"
                f" p99 {_pct(ms, 99):.0f} ms, server alive: {alive}"
                + (f", WRONG: {wrong[:5]}" if wrong else "")
            )
        # The stop, while four clients still submit.
        with ThreadPoolExecutor(4) as pool:
            late = pool.submit(_burst, url, tokens, 4, 4000, 900_000)
            time.sleep(0.5)  # let them be in the middle of their requests
            web = children.procs.pop("web")
            stop_started = time.perf_counter()
            os.killpg(web.pid, signal.SIGTERM)
            try:
                status = web.wait(timeout=60)
            except subprocess.TimeoutExpired:
                status = None
            stopped = time.perf_counter() - stop_started
            late_counts = collections.Counter(s for _, s, _ in late.result())
        print(
            f"SIGTERM under load: exit status {status} after {stopped:.2f} s; the late clients'"
            f" answers {dict(sorted(late_counts.items(), key=str))}"
        )
        log = (var_dir / "web.log").read_text(errors="replace")
        if "Fatal Python error" in log or status != 0:
            failures += 1
            print(log[-3000:])
    finally:
        children.stop()
    print("all bursts answered, clean stop" if failures == 0 else f"{failures} FAILURES")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
