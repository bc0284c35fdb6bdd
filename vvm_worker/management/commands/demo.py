"""``manage.py demo``: the whole local system in the foreground, stopped cleanly by Ctrl-C.

Starts the embedded Redis (unless REDIS_URL is set), the web server (daphne, ASGI) and runs
the scenario's fleet in this process at the given time acceleration, so the run can be
watched in the browser. The web server keeps running after the scenario ends.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from django.conf import settings
from django.core.management import call_command
from django.core.management.base import BaseCommand, CommandError, CommandParser

from accounts.models import User
from cpcc_site.embedded_redis import EmbeddedRedis
from fleet.models import Vehicle
from missions.models import ACTIVE_STATUSES, VirtualVehicle, VVStatus
from vvm_worker.scenario import ScenarioError, load_scenario
from vvm_worker.scenario_loader import PASSWORD_ENV
from vvm_worker.simulation import Progress, Simulation

DEFAULT_SCENARIO = settings.BASE_DIR / "examples" / "scenarios" / "paper-fig3.json"
WEB_START_TIMEOUT_S = 30.0


def _demo_password(name: str) -> str:
    """A password kept in var/ so that every demo run shows the same logins."""
    path = Path(settings.VAR_DIR) / f"demo-{name}-password.txt"
    if path.exists():
        return path.read_text().strip()
    path.parent.mkdir(parents=True, exist_ok=True)
    password = secrets.token_urlsafe(9)
    path.write_text(password + "\n")
    path.chmod(0o600)
    return password


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _wait_for_port(host: str, port: int, process: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + WEB_START_TIMEOUT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise CommandError(f"the web server exited with code {process.returncode}")
        with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=0.5):
            return
        time.sleep(0.1)
    raise CommandError(f"the web server did not answer on {host}:{port}")


class Command(BaseCommand):
    help = "Run the whole local system (web, Redis, the scenario's fleet) until Ctrl-C."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("--scenario", default=str(DEFAULT_SCENARIO), help="scenario file")
        parser.add_argument(
            "--speed",
            type=float,
            default=None,
            help="time acceleration of the simulated fleet (default: CPCC_SIM_SPEED)",
        )
        parser.add_argument("--port", type=int, default=8000)
        parser.add_argument("--host", default="127.0.0.1")
        parser.add_argument("--seed", type=int, default=1)

    def handle(self, *args: Any, **options: Any) -> None:
        speed = settings.CPCC_SIM_SPEED if options["speed"] is None else options["speed"]
        try:
            scenario = load_scenario(options["scenario"])
        except ScenarioError as exc:
            raise CommandError(f"scenario error: {exc}") from None
        call_command("migrate", verbosity=0, interactive=False)
        redis = EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET) if not settings.REDIS_URL else None
        web: subprocess.Popen[bytes] | None = None
        # A service manager stops with SIGTERM: clean up as for Ctrl-C.
        signal.signal(signal.SIGTERM, _interrupt)
        try:
            if redis is not None:
                redis.start()
            admin_password = self._admin()
            os.environ.setdefault(PASSWORD_ENV, _demo_password("customer"))
            self._retire_previous_runs()
            web = subprocess.Popen(
                [sys.executable, "-m", "daphne", "-b", options["host"], "-p", str(options["port"]),
                 "cpcc_site.asgi:application"],
                stdin=subprocess.DEVNULL,
            )  # fmt: skip
            _wait_for_port(options["host"], options["port"], web)
            simulation = Simulation(scenario, seed=options["seed"], speed=speed)
            loaded = simulation.start()
            url = f"http://{options['host']}:{options['port']}/"
            self.stdout.write(self.style.SUCCESS(f"CPCC is running at {url}"))
            self.stdout.write(f"  admin: admin / {admin_password}  ({url}admin/)")
            for username, password in loaded.logins:
                self.stdout.write(f"  customer: {username} / {password or '(unchanged)'}")
            self.stdout.write(
                f"Running {scenario.name!r} at speed {speed:g}. Ctrl-C stops everything."
            )
            simulation.drain(progress=self._reporter(), total=simulation.vv_count)
            self.stdout.write(
                self.style.SUCCESS("The scenario has ended; the web server keeps running.")
            )
            while web.poll() is None:
                time.sleep(0.5)
        except KeyboardInterrupt:
            self.stdout.write("\nStopping.")
        finally:
            if web is not None and web.poll() is None:
                web.terminate()
                try:
                    web.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    web.kill()
            if redis is not None:
                redis.stop()

    def _admin(self) -> str:
        password = os.environ.get("CPCC_ADMIN_PASSWORD") or _demo_password("admin")
        user, _ = User.objects.get_or_create(
            username="admin", defaults={"is_staff": True, "is_superuser": True}
        )
        user.is_staff = user.is_superuser = True
        user.set_password(password)
        user.save()
        return password

    def _retire_previous_runs(self) -> None:
        """VVs an interrupted demo left running are cancelled; vehicles start at their depot."""
        VirtualVehicle.objects.filter(status__in=(VVStatus.QUEUED, *ACTIVE_STATUSES)).update(
            status=VVStatus.CANCELLED, host_rv=None, pending=None, error="cancelled: demo restarted"
        )
        for vehicle in Vehicle.objects.all():
            Vehicle.objects.filter(pk=vehicle.pk).update(
                lat=vehicle.depot_lat, lng=vehicle.depot_lng, alt=vehicle.depot_alt, phase="landed"
            )

    def _reporter(self) -> Any:
        last = [-1, -1]

        def report(p: Progress) -> None:
            if [p.vvs_ended, p.tasks_done] != last:
                last[:] = [p.vvs_ended, p.tasks_done]
                self.stdout.write(
                    f"  t={p.time_s:7.1f} s  tasks done {p.tasks_done:4d}  VVs ended {p.vvs_ended}/{p.vvs_total}"
                )

        return report
