"""What the live benchmarks (``bench.load``, ``bench.platform``, ``bench.submit_burst``) share:
the processes they start, the CPU those use, fresh databases and the web server's socket."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REQUEST_TIMEOUT_S = 10.0
START_TIMEOUT_S = 120.0


# --- processes ----------------------------------------------------------------------------


def _die_with_parent() -> None:
    """In a child, before exec: SIGTERM when the bench dies, even by SIGKILL (Linux)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class Children:
    """The processes the bench starts, each in a process group of its own, with its log."""

    def __init__(self, env: dict[str, str], logs: Path) -> None:
        self.env = env
        self.logs = logs
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, label: str, args: list[str], pass_fds: tuple[int, ...] = ()) -> None:
        log = (self.logs / f"{label}.log".replace(" ", "_")).open("wb")
        self.procs[label] = subprocess.Popen(
            [sys.executable, *args],
            cwd=ROOT,
            env=self.env,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            pass_fds=pass_fds,
            start_new_session=True,  # Ctrl-C reaches the bench, which stops them in order
            preexec_fn=_die_with_parent,
        )
        log.close()

    def log(self, label: str) -> str:
        path = self.logs / f"{label}.log".replace(" ", "_")
        return path.read_text(errors="replace") if path.exists() else ""

    def check(self) -> None:
        for label, proc in self.procs.items():
            if proc.poll() is not None:
                tail = "\n".join(self.log(label).splitlines()[-15:])
                raise SystemExit(f"{label} exited with code {proc.returncode}:\n{tail}")

    def pids(self, prefix: str) -> list[int]:
        return [p.pid for label, p in self.procs.items() if label.startswith(prefix)]

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + 20
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


# --- CPU accounting -------------------------------------------------------------------------

TICK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used, 0 once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / TICK


def children_of(pid: int) -> list[int]:
    """The processes ``pid`` started that still run (an RV worker's planner process)."""
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError):
                if int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    found.append(int(proc.name))
    return found


def pids_of(comm: str, in_cmdline: str) -> list[int]:
    """Processes of that name whose command line has ``in_cmdline`` (a server's port)."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if (proc / "comm").read_text().strip() == comm and in_cmdline in (
                proc / "cmdline"
            ).read_text():
                found.append(int(proc.name))
    return found


# --- databases and the web server's socket -----------------------------------------------------


def fresh_postgres(url: str) -> None:
    """Drop and create the PostgreSQL database ``url`` names."""
    import psycopg

    base, _, name = url.rpartition("/")
    admin = base.replace("postgres://", "postgresql://", 1) + "/postgres"
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.execute(f'CREATE DATABASE "{name}"')


def fresh_redis(url: str) -> None:
    """Empty the Redis database ``url`` names."""
    import redis

    client = redis.Redis.from_url(url)
    client.flushdb()
    client.close()


def listening_socket(port: int) -> socket.socket:
    """The web server's socket, bound here and handed to every daphne process (``--fd``):
    the kernel spreads the connections over the processes that accept on it."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", port))
    sock.listen(1024)
    sock.set_inheritable(True)
    return sock
