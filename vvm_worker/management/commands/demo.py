"""``manage.py demo``: the whole local system in the foreground, stopped cleanly by Ctrl-C.

Starts the embedded Redis (unless REDIS_URL is set), loads the scenario, and runs the web
server (daphne, ASGI), one ground-station worker per GS, the notify worker (webhooks and
e-mails) and one RV worker hosting all the scenario's RVs, as processes of their own, exactly
as they would run on separate machines (a server of simulated vehicles; with ``--mavlink``,
each with its simulated autopilot, a ``mavsim`` process of its own). Fleet events of the
scenario are applied at their (accelerated) time; a vehicle added by one gets an RV worker of
its own. Everything keeps running after the scenario ends.

Without ``--scenario`` it runs the paper's Figure 3 and, next to it on the same fleet for a
customer of their own, the examples of VVs that message each other and look at their pictures
(``examples/scenarios/messages-and-images.json``); ``--also`` adds other scenarios to the one
chosen.

Its terminal shows the platform's own lines and every error, not a line for each request the
web server answers (``--access-log`` shows those too). Besides the administrator and each
customer's own login (its owner), there is a viewer of the first customer (read only) and a
pilot of every RV (staff in the pilot group, not on duty: the demo's RVs fly without one,
CPCC_REQUIRE_PILOT being off), so that both roles can be tried. The logins are kept in
``demo-logins.txt`` of the var folder (CPCC_VAR_DIR) as well, and printed again when the user
presses Enter.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from django.conf import settings
from django.core.management import call_command
from django.core.management.base import BaseCommand, CommandError, CommandParser

from cpcc_site.embedded_redis import EmbeddedRedis
from fleet.models import Driver, Vehicle
from fleet.sources import autopilot_source
from missions.models import ENDED_STATUSES, Task, TaskStatus, VirtualVehicle
from vvm_worker.platform import platform_vvm
from vvm_worker.scenario import FleetEvent, ScenarioError, load_scenario
from vvm_worker.services import user_set_login, vehicle_update
from vvm_worker.services.scenarios import (
    demo_people,
    demo_reset,
    scenario_apply,
    scenario_event_apply,
    scenario_submit_all,
)

DEFAULT_SCENARIO = settings.BASE_DIR / "examples" / "scenarios" / "paper-fig3.json"
# What runs next to the default scenario (and only then): its own customer, the same fleet.
DEFAULT_ALSO = settings.BASE_DIR / "examples" / "scenarios" / "messages-and-images.json"
START_TIMEOUT_S = 60.0
# How long the stop waits for the processes (a worker lets its task in progress end first).
STOP_S = 30.0
# Celery warns in every worker that runs as root. The demo is a local tool, often run as root in
# a container, where the warning (once per worker) only pushed the logins off the screen: its
# processes ignore that one warning, by a Python warning filter on the start of its message, its
# category (celery's SecurityWarning is a UserWarning) and the module that warns. Every other
# warning still shows; a PYTHONWARNINGS of the environment still applies, before this filter.
ROOT_WORKER_WARNING_FILTER = (
    "ignore:You're running the worker with superuser privileges:UserWarning:celery.platforms"
)


def _demo_secret(name: str, nbytes: int = 9) -> str:
    """A secret kept in var/ so that every demo run shows the same logins (and keeps its
    sessions)."""
    path = Path(settings.VAR_DIR) / f"demo-{name}.txt"
    if path.exists():
        return path.read_text().strip()
    secret = secrets.token_urlsafe(nbytes)
    _write_private(path, secret + "\n")
    return secret


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path``, readable by this user alone from the start (mode 0600, also
    when the file was there before with another mode)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "w") as file:
        os.fchmod(file.fileno(), 0o600)
        file.write(text)


def _demo_password(name: str) -> str:
    return _demo_secret(f"{name}-password")


def _served_as_in_production(host: str) -> dict[str, str]:
    """The environment of the demo's processes: DEBUG off, as in production (the site's own
    error pages, never Django's debug pages that list every URL; static files collected with
    hashed names), over plain HTTP on this machine. What the environment sets wins."""
    hosts = (
        "*" if host in ("0.0.0.0", "::") else ",".join([host, "localhost", "127.0.0.1", "[::1]"])
    )
    chosen = {
        "DEBUG": "0",
        "SECRET_KEY": _demo_secret("secret-key", 48),
        "ALLOWED_HOSTS": hosts,
        "CPCC_HTTPS": "0",
        # Webhooks to a receiver on this machine (a customer trying them out); e-mails are
        # printed by the workers (no EMAIL_HOST: Django's console backend).
        "CPCC_WEBHOOK_ALLOW_PRIVATE": "1",
        # The RVs fly without a pilot on duty; the demo's pilot may take them on duty to try.
        "CPCC_REQUIRE_PILOT": "0",
    }
    env = {**chosen, **os.environ}
    # (Of two filters for one warning, the one given last wins: this one, over the environment's.)
    env["PYTHONWARNINGS"] = ",".join(
        filter(None, [env.get("PYTHONWARNINGS"), ROOT_WORKER_WARNING_FILTER])
    )
    return env


class EnterKey:
    """Calls ``pressed`` each time the user presses Enter in the terminal the demo runs in,
    while the demo waits (``wait``). Only a terminal is listened to: under a test, a pipe or a
    service manager nobody presses Enter, and an input at its end would be readable for ever."""

    def __init__(self, stdin: TextIO | None, pressed: Callable[[], None]) -> None:
        self.fd = stdin.fileno() if stdin is not None and stdin.isatty() else None
        self.pressed = pressed

    @property
    def listening(self) -> bool:
        return self.fd is not None

    def wait(self, seconds: float) -> None:
        """Wait ``seconds``, or less when Enter is pressed (``pressed`` is called first)."""
        if self.fd is None or not self._in_foreground():
            time.sleep(seconds)
            return
        ready, _, _ = select.select([self.fd], [], [], seconds)
        if ready:
            # A terminal hands over whole lines; what was typed before Enter does not matter.
            if os.read(self.fd, 4096):
                self.pressed()
            else:  # Ctrl-D: the end of the input, nothing more to listen to
                self.fd = None

    def _in_foreground(self) -> bool:
        """Whether the terminal's input is the demo's now: a demo sent to the background (``&``,
        Ctrl-Z and ``bg``) that read from it would be stopped by the terminal (SIGTTIN)."""
        assert self.fd is not None
        try:
            return os.tcgetpgrp(self.fd) == os.getpgrp()
        except OSError:  # not this process's controlling terminal
            return False


# What stops the demo: Ctrl-C, a service manager's SIGTERM, a closed terminal's SIGHUP.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Processes:
    """The demo's child processes, each in a process group of its own."""

    def __init__(self, env: dict[str, str]) -> None:
        self.env = env
        self.children: dict[str, subprocess.Popen[bytes]] = {}
        self.hurry = threading.Event()

    def catch_interrupts(self) -> None:
        """The first Ctrl-C (or SIGTERM, as a service manager stops, or SIGHUP, as a closed
        terminal hangs up) raises KeyboardInterrupt and, before it does, makes the next one set
        ``hurry``: a second Ctrl-C that comes at once, even before the demo has printed that it
        is stopping, kills what is left."""

        def again(signum: int, frame: object) -> None:
            self.hurry.set()

        def first(signum: int, frame: object) -> None:
            for each in STOP_SIGNALS:
                signal.signal(each, again)
            raise KeyboardInterrupt

        for signum in STOP_SIGNALS:
            signal.signal(signum, first)

    def start(self, label: str, *args: str) -> subprocess.Popen[bytes]:
        process = subprocess.Popen(
            [sys.executable, *args],
            env=self.env,
            stdin=subprocess.DEVNULL,
            start_new_session=True,  # Ctrl-C reaches the demo, which stops the children in order
        )
        self.children[label] = process
        return process

    def check(self) -> None:
        for label, process in self.children.items():
            if process.poll() is not None:
                raise CommandError(f"{label} exited with code {process.returncode}")

    def stop(self) -> list[str]:
        """SIGTERM every child, then wait for each (STOP_S at most; a second Ctrl-C or SIGTERM
        kills what is left at once). Returns a line for each child that did not exit 0."""
        for signum in STOP_SIGNALS:
            signal.signal(signum, lambda signum, frame: self.hurry.set())
        for process in self.children.values():
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_S
        problems = []
        for label, process in self.children.items():
            while process.poll() is None:
                if self.hurry.is_set() or time.monotonic() > deadline:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
                    problems.append(f"{label}: killed (it had not stopped)")
                    break
                with contextlib.suppress(subprocess.TimeoutExpired):
                    process.wait(timeout=0.1)
            else:
                if process.returncode != 0:
                    problems.append(f"{label}: exit status {process.returncode}")
        return problems


def _scenario_paths(options: dict[str, Any]) -> list[str]:
    """The scenario files to run: ``--scenario`` (the paper's Figure 3 by default) and then
    ``--also``'s, which without either option are the examples of messages and pictures."""
    also = options["also"]
    if also is None:
        also = [str(DEFAULT_ALSO)] if options["scenario"] is None else []
    return [options["scenario"] or str(DEFAULT_SCENARIO), *also]


def _login_line(kind: str, username: str, password: str | None, label: str | None) -> str:
    """A scenario's login as the demo prints it: a customer's own (its owner) as before; one of
    a customer's users or staff the scenario names with who they are."""
    line = f"  {kind}: {username} / {password or '(unchanged)'}"
    return f"{line}  ({label})" if label else line


def _wait_for_port(host: str, port: int, processes: Processes) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        processes.check()
        with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=0.5):
            return
        time.sleep(0.1)
    raise CommandError(f"the web server did not answer on {host}:{port}")


class Command(BaseCommand):
    help = "Run the whole local system (web, Redis, a worker per GS, one for the RVs) until Ctrl-C."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "--scenario",
            default=None,
            help="scenario file (default: the paper's Figure 3, with the examples of messages "
            "and pictures next to it)",
        )
        parser.add_argument(
            "--also",
            action="append",
            default=None,
            metavar="FILE",
            help="another scenario to run next to --scenario: its ground stations, vehicles "
            "(a vehicle of the same name is updated), customers, VVs and fleet events are added "
            "(repeatable; by default messages-and-images.json when --scenario is not given, "
            "none when it is)",
        )
        parser.add_argument(
            "--speed",
            type=float,
            default=None,
            help="time acceleration of the simulated fleet, 0 = instant flights (default: CPCC_SIM_SPEED)",
        )
        parser.add_argument("--port", type=int, default=8000)
        parser.add_argument("--host", default="127.0.0.1")
        parser.add_argument(
            "--mavlink",
            action="store_true",
            help="fly every RV over MAVLink: a `mavsim` process per RV (a simulated ArduPilot "
            "copter on a loopback UDP port) and its worker's MAVLink driver",
        )
        parser.add_argument(
            "--access-log",
            nargs="?",
            const="-",
            default=None,
            metavar="FILE",
            help="log every request the web server answers, in this terminal (or in FILE); "
            "without it, only errors and the platform's own lines show",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        speed = settings.CPCC_SIM_SPEED if options["speed"] is None else options["speed"]
        if options["mavlink"] and speed <= 0:
            raise CommandError("--mavlink needs --speed > 0: a MAVLink copter cannot fly instantly")
        self.mavlink = options["mavlink"]
        try:
            scenarios = [load_scenario(path) for path in _scenario_paths(options)]
        except ScenarioError as exc:
            raise CommandError(f"scenario error: {exc}") from None
        call_command("migrate", verbosity=0, interactive=False)
        redis = EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET) if not settings.REDIS_URL else None
        redis_url = settings.REDIS_URL or f"unix://{settings.EMBEDDED_REDIS_SOCKET}"
        env = {
            **_served_as_in_production(options["host"]),
            "REDIS_URL": redis_url,
            "CPCC_SIM_SPEED": str(speed),
        }
        # For the web server's WhiteNoise with DEBUG off (hashed names, compressed copies),
        # under the web server's settings; copies only what changed since the last run.
        manage = str(Path(settings.BASE_DIR) / "manage.py")
        subprocess.run(
            [sys.executable, manage, "collectstatic", "--noinput", "-v", "0"], env=env, check=True
        )
        processes = Processes(env)
        processes.catch_interrupts()
        try:
            if redis is not None:
                redis.start()
            admin_password = settings.CPCC_ADMIN_PASSWORD or _demo_password("admin")
            user_set_login(username="admin", password=admin_password, staff=True)
            demo_reset(reason="cancelled: demo restarted")
            password = settings.CPCC_SCENARIO_PASSWORD or _demo_password("customer")
            loaded = [
                scenario_apply(scenario=scenario, password=password) for scenario in scenarios
            ]
            # One worker per ground station and vehicle, however many scenarios name it.
            ground_stations = {
                name: gs for each in loaded for name, gs in each.ground_stations.items()
            }
            vehicles = {name: vehicle for each in loaded for name, vehicle in each.vehicles.items()}
            # To try the roles: a viewer of the first customer, a pilot of every RV.
            first_customer = next(
                (customer for each in loaded for customer in each.customers.values()), None
            )
            viewer, pilot = demo_people(
                customer=first_customer, vehicles=list(vehicles.values()), password=password
            )
            # daphne's verbosity 0 turns off its access log (a line for every static file and
            # map tile, a thousand in a few minutes) and nothing else: the web process logs
            # through Django's LOGGING (settings.py), errors and the platform's own lines.
            access_log = options["access_log"]
            processes.start(
                "web",
                "-m",
                "daphne",
                "-b",
                options["host"],
                "-p",
                str(options["port"]),
                *(["--access-log", access_log] if access_log else ["--verbosity", "0"]),
                "cpcc_site.asgi:application",
            )
            _wait_for_port(options["host"], options["port"], processes)
            for name in ground_stations:
                processes.start(f"gsworker {name}", manage, "gsworker", name)
            processes.start("notifyworker", manage, "notifyworker")  # webhooks, e-mails
            rv_workers = self._start_vehicles(list(vehicles.values()), processes, manage)
            vvs = [
                vv
                for scenario, its in zip(scenarios, loaded, strict=True)
                for vv in scenario_submit_all(scenario=scenario, loaded=its, vvm=platform_vvm())
            ]
            url = f"http://{options['host']}:{options['port']}/"
            self.logins = [
                f"CPCC is running at {url}",
                f"  admin: admin / {admin_password}  ({url}admin/)",
                *(
                    _login_line(
                        "staff" if username in each.staff else "customer",
                        username,
                        login_password,
                        each.labels.get(username),
                    )
                    for each in loaded
                    for username, login_password in each.logins
                ),
            ]
            if viewer is not None and first_customer is not None:
                self.logins.append(
                    f"  viewer: {viewer.username} / {password}  ({first_customer.name}, read only)"
                )
            flown = ", ".join(vehicles) or "no RV"
            self.logins.append(
                f"  pilot: {pilot.username} / {password}  (staff, may fly {flown}; not on duty)"
            )
            self.logins_path = Path(settings.VAR_DIR) / "demo-logins.txt"
            _write_private(self.logins_path, "\n".join(self.logins) + "\n")
            self.enter = EnterKey(sys.stdin, pressed=self._show_logins)
            self._show_logins()
            names = " and ".join(repr(scenario.name) for scenario in scenarios)
            self.stdout.write(
                f"Running {names} at speed {speed:g} with {len(ground_stations)} "
                f"ground-station and {len(vehicles)} vehicle worker(s), the vehicles' in "
                f"{rv_workers} process(es). Ctrl-C stops everything."
            )
            # The fleet events of every scenario, in the order of their times.
            events = sorted((e for s in scenarios for e in s.events), key=lambda e: e.at_s)
            self._follow(events, [vv.pk for vv in vvs], speed, processes, manage)
            self.stdout.write(
                self.style.SUCCESS("The scenario has ended; everything keeps running.")
            )
            while True:
                processes.check()
                self.enter.wait(0.5)
        except KeyboardInterrupt:
            with contextlib.suppress(OSError):  # the terminal may be gone (SIGHUP)
                self.stdout.write("\nStopping (Ctrl-C again stops at once).")
        finally:
            problems = processes.stop()
            if redis is not None:
                redis.stop()
            with contextlib.suppress(OSError):
                for problem in problems:
                    self.stderr.write(problem)

    def _follow(
        self,
        events: list[FleetEvent],
        vv_ids: list[Any],
        speed: float,
        processes: Processes,
        manage: str,
    ) -> None:
        """Print progress until this run's VVs have ended, applying fleet events (in the order
        of their times) on time."""
        started = time.monotonic()
        events = list(events)
        last = None
        while True:
            processes.check()
            elapsed_s = (time.monotonic() - started) * (speed if speed > 0 else float("inf"))
            while events and events[0].at_s <= elapsed_s:
                self._apply(events.pop(0), processes, manage)
            mine = VirtualVehicle.objects.filter(pk__in=vv_ids)
            ended = mine.filter(status__in=ENDED_STATUSES).count()
            done = Task.objects.filter(vv__in=vv_ids, status=TaskStatus.DONE).count()
            if (ended, done) != last:
                last = (ended, done)
                self.stdout.write(f"  tasks done {done:4d}  VVs ended {ended}/{len(vv_ids)}")
            if ended == len(vv_ids) and not events:
                for vv in mine.order_by("name"):
                    self.stdout.write(
                        f"  {vv.name} ({vv.customer}): {vv.status} {vv.error}".rstrip()
                    )
                return
            self.enter.wait(0.25)

    def _show_logins(self) -> None:
        first, *rest = self.logins
        self.stdout.write(self.style.SUCCESS(first))
        for line in rest:
            self.stdout.write(line)
        again = "; press Enter to print them again" if self.enter.listening else ""
        self.stdout.write(f"  (these logins are kept in {self.logins_path}{again})")

    def _start_vehicles(self, vehicles: list[Vehicle], processes: Processes, manage: str) -> int:
        """Start one RV worker for these vehicles; with --mavlink, first each one's simulated
        copter, which the worker reaches over a loopback UDP port. Returns how many worker
        processes it started (none for no vehicles)."""
        if not vehicles:
            return 0
        names = []
        ports = iter(_free_udp_ports(len(vehicles) if self.mavlink else 0))
        for vehicle in vehicles:
            if self.mavlink:
                port = next(ports)
                # Every reading over MAVLink too, as mavsim publishes it (from the same
                # simulated world the platform would read otherwise).
                sources = {
                    sensor.name: autopilot_source(sensor.as_catalog_entry()).as_json()
                    for sensor in vehicle.sensors.all()
                }
                vehicle = vehicle_update(
                    vehicle=vehicle,
                    config={
                        "driver": Driver.MAVLINK,
                        "driver_url": f"udpout:127.0.0.1:{port}",
                        "sensor_sources": sources,
                    },
                    sensors=None,
                    vvm=platform_vvm(),
                )
                processes.start(f"mavsim {vehicle.name}", manage, "mavsim", vehicle.name)
            names.append(vehicle.name)
        processes.start(f"rvworker {', '.join(names)}", manage, "rvworker", *names)
        return 1

    def _apply(self, event: FleetEvent, processes: Processes, manage: str) -> None:
        def start_worker(vehicle: Vehicle) -> None:
            self._start_vehicles([vehicle], processes, manage)

        vehicle = scenario_event_apply(event=event, vvm=platform_vvm(), on_added=start_worker)
        self.stdout.write(f"  event: {vehicle.name} {event.action}")


def _free_udp_ports(count: int) -> list[int]:
    """``count`` different loopback UDP ports free now. The probes stay bound until all are
    chosen: one closed before the next is taken could give its port again, and two simulated
    copters would share it (each vehicle's worker would then talk to both)."""
    with contextlib.ExitStack() as stack:
        probes = [
            stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
            for _ in range(count)
        ]
        for probe in probes:
            probe.bind(("127.0.0.1", 0))
        return [probe.getsockname()[1] for probe in probes]
