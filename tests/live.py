"""The distributed platform for end-to-end tests: real Celery workers in subprocesses on a real
Redis (the embedded server, or REDIS_URL's), sharing the test database (SQLite file or
PostgreSQL). Tests using it need ``django_db(transaction=True)`` so their data is committed."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
from django.conf import settings
from django.db import connection

from tests.polling import wait_until
from vvm_worker.services.waiting import PLATFORM_NOTE

ROOT = Path(__file__).resolve().parents[1]


def database_url() -> str:
    """The test database as a URL a worker process can open."""
    conf = connection.settings_dict
    if conf["ENGINE"] == "django.db.backends.sqlite3":
        return f"sqlite:///{conf['NAME']}"
    user = conf["USER"] or ""
    password = f":{conf['PASSWORD']}" if conf["PASSWORD"] else ""
    host = conf["HOST"] or "127.0.0.1"
    port = f":{conf['PORT']}" if conf["PORT"] else ""
    return f"postgres://{user}{password}@{host}{port}/{conf['NAME']}"


def program_log(vv: Any) -> list[str]:
    """The lines a VV's program logged, in order, without the notes the platform adds (a VV
    that waited for a vehicle while a worker was gone has them; a run without faults has
    none): what two runs of one program must agree on."""
    lines = vv.log.exclude(level=PLATFORM_NOTE).order_by("seq")
    return list(lines.values_list("message", flat=True))


class Workers:
    """Worker processes of one test: started with the test database and broker, and stopped
    (or killed) at the end."""

    def __init__(self, tmp: Path, redis_url: str, speed: float) -> None:
        self.tmp = tmp
        self.env = {
            **os.environ,
            "REDIS_URL": redis_url,
            "CPCC_SIM_SPEED": str(speed),
            "CPCC_RV_LEASE_S": "3",
            "CPCC_VAR_DIR": str(tmp / "var"),
            "CPCC_MEDIA_ROOT": str(settings.MEDIA_ROOT),
            "PYTHONFAULTHANDLER": "1",  # a crash leaves its Python stack in the log
        }
        self.processes: dict[str, subprocess.Popen[bytes]] = {}

    def start(
        self,
        kind: str,
        name: str,
        *more: str,
        env: dict[str, str] | None = None,
        options: Sequence[str] = (),
    ) -> subprocess.Popen[bytes]:
        """Start ``manage.py gsworker NAME`` or ``rvworker NAME [NAME ...]`` (one process
        hosting several RVs, known to ``kill`` and ``terminate`` by its first name); returns
        once it runs. ``env``: more variables (a fault to inject: tests/inject/sitecustomize.py);
        ``options``: the command's options (``--station GS``, say)."""
        names = [name, *more]
        group = f"+{len(more)}" if more else ""  # the file of a group is named by its first
        log = (self.tmp / f"{kind}-{name}{group}.log".replace(" ", "_")).open("ab")
        logged = log.tell()
        process = subprocess.Popen(
            [sys.executable, "manage.py", kind, *names, *options],
            cwd=ROOT,
            env={**self.env, "DATABASE_URL": database_url(), **faults(env or {})},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # a process group of its own, to kill it with its children
        )
        self.processes[name] = process
        path = Path(log.name)
        # The log is appended to: only what this process wrote says that it runs.
        started = f"{kind} {', '.join(names)}:".encode()
        wait_until(
            lambda: started in path.read_bytes()[logged:] or process.poll() is not None,
            timeout=60,
            what=f"{kind} {', '.join(names)} to start",
        )
        assert process.poll() is None, path.read_text()
        return process

    def kill(self, name: str) -> None:
        """SIGKILL a worker and everything it started, as a crash would."""
        process = self.processes.pop(name)
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)

    def terminate(self, name: str, timeout: float = 30) -> int:
        """SIGTERM a worker, as systemd or an operator stops it; returns its exit status
        (negative: the signal that ended it)."""
        process = self.processes.pop(name)
        os.killpg(process.pid, signal.SIGTERM)
        try:
            return process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            # Where it hangs: faulthandler (PYTHONFAULTHANDLER) writes every thread's stack to
            # the log on SIGABRT.
            os.kill(process.pid, signal.SIGABRT)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
            raise AssertionError(
                f"{name} still ran {timeout:g} s after SIGTERM\n{self.logs()}"
            ) from None

    def stop_all(self) -> None:
        for process in self.processes.values():
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
        for process in self.processes.values():
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
        self.processes.clear()

    def logs(self) -> str:
        """The end of every worker's log, and the VVs' state: what a timed-out test shows."""
        from missions.models import VirtualVehicle

        parts = [
            f"--- {p.name}\n{_quiet(p.read_text())[-4000:]}" for p in sorted(self.tmp.glob("*.log"))
        ]
        for vv in VirtualVehicle.objects.select_related("host_gs", "host_rv"):
            tasks = list(vv.tasks.values_list("q", "status", "vehicle__name"))
            parts.append(
                f"VV {vv.name}: {vv.status} on {vv.host_name} pending={bool(vv.pending)} tasks={tasks}"
            )
        return "\n".join(parts)


def faults(env: dict[str, str]) -> dict[str, str]:
    """``env`` with tests/inject on PYTHONPATH when it names a fault to inject."""
    if not any(name.startswith("CPCC_FAULT_") for name in env):
        return env
    path = os.pathsep.join(
        filter(None, [str(ROOT / "tests" / "inject"), os.environ.get("PYTHONPATH")])
    )
    return {**env, "PYTHONPATH": path}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def production_env(var_dir: Path) -> dict[str, str]:
    """The environment of a production web server on 127.0.0.1 over plain HTTP (DEBUG off)."""
    return {
        **os.environ,
        "DEBUG": "0",
        "SECRET_KEY": "test-only-" + "x" * 50,
        "ALLOWED_HOSTS": "127.0.0.1",
        "CPCC_HTTPS": "0",
        "CPCC_VAR_DIR": str(var_dir),
    }


def collect_static(var_dir: Path) -> Path:
    """What a provider does before starting the web server with DEBUG off: `collectstatic`
    (into ``var_dir``/staticfiles, which WhiteNoise then serves)."""
    subprocess.run(
        [sys.executable, "manage.py", "collectstatic", "--noinput"],
        cwd=ROOT,
        env=production_env(var_dir),
        check=True,
        capture_output=True,
    )
    return var_dir


class Web:
    """The web server as a provider runs it (daphne, ASGI, or gunicorn, WSGI; DEBUG off) in a
    process of its own,
    on a free port of 127.0.0.1, with the test database and broker; ``var_dir`` holds the
    collected static files (``collect_static``)."""

    def __init__(self, tmp: Path, redis_url: str, var_dir: Path) -> None:
        self.tmp = tmp
        # "daphne" (HTTP and the map's sockets), or "gunicorn": its WSGI workers for HTTP
        # with the production settings (cpcc_site/gunicorn_conf.py).
        self.server = "daphne"
        self.port = free_port()
        self.env = {
            **production_env(var_dir),
            "REDIS_URL": redis_url,
            "CPCC_MEDIA_ROOT": str(settings.MEDIA_ROOT),
            "DATABASE_URL": database_url(),
            "PYTHONFAULTHANDLER": "1",
        }
        self.process: subprocess.Popen[bytes] | None = None
        self.log = tmp / "web.log"

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.port}{path}"

    def start(self) -> None:
        """Start it; returns once it answers."""
        log = self.log.open("ab")
        command = {
            "daphne": [
                "daphne",
                "-b",
                "127.0.0.1",
                "-p",
                str(self.port),
                "cpcc_site.asgi:application",
            ],
            "gunicorn": [
                "gunicorn",
                "-c",
                "python:cpcc_site.gunicorn_conf",
                "--workers",
                "2",
                "--bind",
                f"127.0.0.1:{self.port}",
                "cpcc_site.wsgi",
            ],
        }[self.server]
        self.process = subprocess.Popen(
            [sys.executable, "-m", *command],
            cwd=ROOT,
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        process = self.process

        def up() -> bool:
            assert process.poll() is None, self.log.read_text()
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1):
                    return True
            except OSError:
                return False

        wait_until(up, timeout=60, what="the web server to answer")

    def kill(self) -> None:
        """SIGKILL it, as a crash would."""
        assert self.process is not None
        os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait(timeout=10)
        self.process = None

    def terminate(self, timeout: float = 30) -> int:
        """SIGTERM it, as systemd or an operator stops it; returns its exit status."""
        assert self.process is not None
        os.killpg(self.process.pid, signal.SIGTERM)
        status = self.process.wait(timeout=timeout)
        self.process = None
        return status

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        self.process = None


def _quiet(log: str) -> str:
    """A worker's log without Celery's start-up banner and root warning."""
    return "\n".join(
        line
        for line in log.splitlines()
        if not line.startswith((" ", "-", "[", "absolutely", "Please", "User", "\x1b"))
        and line.strip()
    )


@pytest.fixture(scope="module")
def web_var(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The collected static files of the production web servers of a test module."""
    return collect_static(tmp_path_factory.mktemp("web-var"))


@pytest.fixture
def web(broker_url: str, tmp_path: Path, web_var: Path, transactional_db: None) -> Iterator[Web]:
    """The web server as in production (tests/live.py's Web), stopped at the test's end."""
    server = Web(tmp_path, broker_url, web_var)
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def workers(broker_url: str, tmp_path: Path, transactional_db: None) -> Iterator[Workers]:
    """Worker processes of this test, stopped at its end."""
    pool = Workers(tmp_path, broker_url, speed=25)
    try:
        yield pool
    finally:
        pool.stop_all()
