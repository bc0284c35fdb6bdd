"""A dry run: a program tried against a simulated copy of the fleet before anything flies
(``POST /api/v1/vvs/dry-run/``, the editor's *Dry run*, ``cpcc submit --dry-run``).

The copy is what ``manage.py simulate`` runs (vvm_worker/simulation.py): the vehicles in
service with their areas, altitudes, sensors and speeds, the ground stations and no-fly zones,
the SDC, and one VV of the customer's with the customer's quotas; simulated sensors answer at
once, and time is discrete (a flight takes no wall time). Every report says what its duration
assumes (ASSUMES). The copy runs in a process of its own (``manage.py dry_run_copy``,
vvm_worker/dry_run_copy.py) on a database of its own, a throw-away SQLite file, for three
reasons:

- nothing of the copy can reach the platform's database or its media: no VV, task, storage
  document or picture of a dry run ever exists there;
- the services that the copy runs keep process-wide caches of the fleet (the mapper's shape of
  it, the airspace), which must never mix the copy's fleet with the real one in a web process
  that routes real VVs too;
- a hostile program is bounded from outside: each step has the customer's CPU and heap quotas,
  as a real VV's has, and the whole run a wall-clock limit (DRY_RUN_WALL_S) after which the
  report says how far it got; a process that overruns even that is killed.

A web process runs at most MAX_RUNNING dry runs at once (each is a Python process of about
100 MB for a few seconds), one per customer, handed out in the order they were asked for; a
customer's dry runs may use ``CPCC_DRY_RUN_CPU_S`` seconds of CPU within
``CPCC_DRY_RUN_WINDOW_S`` (vvm_worker/dry_run_places.py). Beyond that a request is refused
with DryRunBusy, which says when to try again: one customer cannot keep the others out.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from django.conf import settings
from django.core.exceptions import ValidationError

from accounts.models import Customer, User
from fleet.models import NoFlyZone, SensorType, Vehicle, VehicleKind
from fleet.selectors import ground_station_list, vehicles_in_service
from fleet.simulation.vehicle import PHASE_LANDED
from missions.models import vv_name_problem
from vvm_worker.dry_run_places import DryRunPlaces, Refused
from vvm_worker.runtime import SyntaxProblem, check_syntax
from vvm_worker.services.vvs import NotACustomer

logger = logging.getLogger("cpcc.dry_run")

# Wall-clock time the copy may compute (programs, planning, the database of the copy) once it
# is loaded; then it stops and reports what it found so far.
DRY_RUN_WALL_S = 20.0
# On top of that: a new Python process, Django, the copy's database. A dry run that has not
# answered by then is killed.
START_ALLOWANCE_S = 40.0
MAX_RUNNING = 2
# How long a request waits for one of the MAX_RUNNING places before it is refused.
WAIT_FOR_PLACE_S = 5.0
_places = DryRunPlaces(MAX_RUNNING)

SETTINGS = "cpcc_site.settings"  # of the copy's process, unless this one names others
COPY_CUSTOMER = "Customer"
# Statuses of the VV in the copy: how it would end, or "unfinished" (the wall-clock limit).
UNFINISHED = "unfinished"
# What a report's duration_s assumes, said with every report: the copy is the platform's own
# simulation, so what it leaves out is what the copy does not hold (where the vehicles are now,
# the other VVs) and the sensors' time.
ASSUMES = (
    "From the submission to the VV's end, with the fleet to itself: each vehicle starts where "
    "it is now (in the air where it flies or stands by, else on the ground at its depot, with "
    "its take-off) and flies at its top speed; the platform picks the vehicles and the order "
    "of the tasks as it would; readings take no time. Other VVs sharing the vehicles make it "
    "longer. No message comes in a dry run: a wait for one is not counted."
)


class DryRunBusy(RuntimeError):
    """A dry run that may not start now: this web process runs as many as it may, one of the
    customer's runs already, or the customer's dry runs used their CPU budget. ``str`` says
    which; ``retry_after_s`` when to try again."""

    def __init__(self, reason: str, retry_after_s: float) -> None:
        super().__init__(reason)
        self.retry_after_s = retry_after_s


class DryRunFailed(RuntimeError):
    """The copy could not be run (the platform's fault, not the program's): ``str`` says why."""


class NoGroundStation(RuntimeError):
    """The platform has no ground station, so no VV can start: there is nothing to try."""


@dataclass(frozen=True)
class DryRunTask:
    """A task the program would ask for, as the copy served it.

    ``status``: ``done`` (a vehicle would read it), ``rejected`` (no vehicle in service could
    serve it: ``message`` says why), ``open`` (still waiting when the dry run stopped) or
    ``cancelled`` (the program ended before it was served). ``line`` and ``column``: the
    ``VV.task.execute`` (or ``executeAll``) call in the program. Times in seconds from the
    submission.
    """

    q: int
    index: int
    position: tuple[float, float, float]
    tolerance_m: float
    sensors: tuple[str, ...]
    status: str
    message: str
    line: int | None
    column: int | None
    requested_s: float | None
    done_s: float | None

    @property
    def servable(self) -> bool:
        return self.status != "rejected"


@dataclass(frozen=True)
class QuotaStop:
    """The quota that would stop the VV, and where: ``quota`` as the runtime names it
    (``tasks``, ``cpu``, ``heap``, ``storage``, ``api_calls``), its message, the place in the
    program when known, the tasks asked for before, and when (seconds from submission)."""

    quota: str
    message: str
    line: int | None
    column: int | None
    tasks_before: int
    at_s: float


@dataclass(frozen=True)
class DryRunReport:
    """What a dry run found.

    ``status``: how the VV would end in the copy (``finished``, ``failed``, ``killed``), or
    ``unfinished`` when the dry run reached its wall-clock limit first. ``error`` (with its
    place) says why a VV failed or was killed. ``duration_s``: from submission to its end in
    the copy (to where the dry run stopped, when unfinished), the vehicles' flights included,
    on the assumptions of ``assumes`` (ASSUMES). ``log``: the lines the program logged.
    ``message_wait_s``: the timeouts of its ``VV.message.receive`` calls that no message
    answered, which ``duration_s`` leaves out (the most it would wait for messages).
    """

    name: str
    status: str
    error: str
    error_line: int | None
    error_column: int | None
    duration_s: float
    tasks: tuple[DryRunTask, ...]
    quota: QuotaStop | None
    log: tuple[str, ...]
    message_wait_s: float = 0.0

    @property
    def assumes(self) -> str:
        return ASSUMES

    @property
    def unservable(self) -> tuple[DryRunTask, ...]:
        return tuple(task for task in self.tasks if not task.servable)

    @property
    def within_quotas(self) -> bool:
        return self.quota is None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> DryRunReport:
        quota = data.get("quota")
        return cls(
            name=str(data["name"]),
            status=str(data["status"]),
            error=str(data.get("error") or ""),
            error_line=data.get("error_line"),
            error_column=data.get("error_column"),
            duration_s=float(data["duration_s"]),
            tasks=tuple(
                DryRunTask(
                    **{
                        **task,
                        "position": tuple(task["position"]),
                        "sensors": tuple(task["sensors"]),
                    }
                )
                for task in data["tasks"]
            ),
            quota=QuotaStop(**quota) if quota else None,
            log=tuple(data.get("log") or ()),
            message_wait_s=float(data.get("message_wait_s") or 0.0),
        )


def vv_dry_run_for_user(
    *, user: User, name: str, program: str, wall_s: float = DRY_RUN_WALL_S
) -> tuple[DryRunReport | None, SyntaxProblem | None]:
    """Try a program of the user's customer against a simulated copy of the fleet (see the
    module's docstring); creates nothing and flies nothing.

    Returns the report, or a program's syntax error with where it is (as a submission would
    refuse it). Raises NotACustomer for a user of no customer, ValidationError for a name a
    submission would refuse, NoGroundStation when no VV could start, DryRunBusy when this
    process runs MAX_RUNNING dry runs already (or one of the customer's, or the customer's
    used their CPU budget), and DryRunFailed when the copy could not run.
    """
    customer = user.customer
    if customer is None:
        raise NotACustomer(f"{user.username} belongs to no customer")
    problem = vv_name_problem(name)
    if problem is not None:
        raise ValidationError({"name": [problem]})
    syntax = check_syntax(program)
    if syntax is not None:
        return None, syntax
    request = {
        "scenario": fleet_copy(name=name, program=program),
        "customer": customer_copy(customer=customer),
        "wall_s": wall_s,
    }
    try:
        _places.take(
            customer.pk,
            wait_s=WAIT_FOR_PLACE_S,
            cpu_budget_s=settings.CPCC_DRY_RUN_CPU_S,
            window_s=settings.CPCC_DRY_RUN_WINDOW_S,
        )
    except Refused as exc:
        raise DryRunBusy(str(exc), exc.retry_after_s) from None
    started = time.monotonic()
    cpu_s: float | None = None
    try:
        report, cpu_s = _run_copy(request, timeout_s=wall_s + START_ALLOWANCE_S)
    finally:
        # A copy that failed or was killed counts the time it took.
        _places.give_back(customer.pk, cpu_s=time.monotonic() - started if cpu_s is None else cpu_s)
    logger.info(
        "dry run",
        extra={
            "customer": customer.slug,
            "user": user.username,
            "status": report.status,
            "tasks": len(report.tasks),
            "unservable": len(report.unservable),
            "cpu_s": round(cpu_s, 2),
        },
    )
    return report, None


def airborne_now(vehicle: Vehicle) -> tuple[float, float, float] | None:
    """Where an aerial RV is in the air now, as its worker last reported (lat, lng, alt), or
    None when it is on the ground (or has not reported): a dry run's copy of it starts there,
    hovering, as an RV standing by in the middle of its area would fly from there."""
    if vehicle.kind != VehicleKind.AERIAL or vehicle.phase == PHASE_LANDED:
        return None
    if vehicle.lat is None or vehicle.lng is None or vehicle.alt is None:
        return None
    if vehicle.alt <= vehicle.depot_alt:
        return None
    return (vehicle.lat, vehicle.lng, vehicle.alt)


def fleet_copy(*, name: str, program: str) -> dict[str, Any]:
    """The fleet as a scenario document (vvm_worker/scenario.py, DESIGN.md section 5) with one
    VV, ``name`` running ``program``, of one customer (COPY_CUSTOMER): the ground stations,
    the RVs in service (a simulated vehicle each where it is now: landed at its depot, or in
    the air where its worker last reported it), the no-fly zones and the SDC.

    Vehicles, stations and zones are numbered, not named: the copy never holds a name it
    could show the customer. An RV with no sensor (it could serve nothing) is left out.
    """
    stations = [
        {"name": f"GS {i}", "position": [gs.lat, gs.lng, gs.alt]}
        for i, gs in enumerate(ground_station_list(), 1)
    ]
    if not stations:
        raise NoGroundStation(
            "The platform has no ground station, so no VV can start now; ask its operator."
        )
    vehicles = []
    for i, vehicle in enumerate(vehicles_in_service(), 1):
        sensors = sorted(s.name for s in vehicle.sensors.all())
        if not sensors:
            continue
        spec: dict[str, Any] = {
            "name": f"RV {i}",
            "depot": [vehicle.depot_lat, vehicle.depot_lng, vehicle.depot_alt],
            "area": vehicle.area,
            "min_altitude_m": vehicle.min_altitude_m,
            "max_altitude_m": vehicle.max_altitude_m,
            "max_speed_mps": vehicle.max_speed_mps,
            "climb_rate_mps": vehicle.climb_rate_mps,
            "sensors": sensors,
            "kind": vehicle.kind,
        }
        if vehicle.battery_s:
            spec["battery_s"] = vehicle.battery_s
        airborne = airborne_now(vehicle)
        if airborne is not None:
            spec["start"] = list(airborne)
        # A scenario gives a rate only to the kinds that have it.
        if vehicle.dive_rate_mps and vehicle.kind == VehicleKind.UNDERWATER:
            spec["dive_rate_mps"] = vehicle.dive_rate_mps
        if vehicle.turn_rate_dps and vehicle.kind in (VehicleKind.GROUND, VehicleKind.SURFACE):
            spec["turn_rate_dps"] = vehicle.turn_rate_dps
        vehicles.append(spec)
    zones = [
        {
            "name": f"zone {i}",
            "area": zone.area,
            "min_altitude_m": zone.min_altitude_m,
            "max_altitude_m": zone.max_altitude_m,
        }
        for i, zone in enumerate(NoFlyZone.objects.order_by("pk"), 1)
    ]
    sensors = [
        {
            "name": s.name,
            "kind": s.kind,
            "unit": s.unit,
            "params": s.params or {},
            "privileged": s.privileged,
            "description": s.description,
            "kinds": list(s.kinds or []),
        }
        for s in SensorType.objects.order_by("pk")
    ]
    return {
        "name": "dry run",
        "ground_stations": stations,
        "vehicles": vehicles,
        "customers": [{"name": COPY_CUSTOMER, "max_parallel_vvs": 1}],
        "vvs": [{"customer": COPY_CUSTOMER, "name": name, "source": program}],
        "sensors": sensors,
        "no_fly_zones": zones,
    }


def customer_copy(*, customer: Customer) -> dict[str, Any]:
    """What of the customer the copy's VV runs with: its quotas, the SDC entries and VVM-API
    calls it may use, and whether it is privileged."""
    return {
        **{field: getattr(customer, field) for field in Customer.QUOTA_FIELDS},
        "privileged": customer.privileged,
        "allowed_api_calls": list(customer.allowed_api_calls or []),
        "allowed_sensors": sorted(customer.allowed_sensors.values_list("name", flat=True)),
    }


def _run_copy(request: dict[str, Any], *, timeout_s: float) -> tuple[DryRunReport, float]:
    """Run the copy in a process of its own (``manage.py dry_run_copy FOLDER``) on a
    throw-away SQLite database in FOLDER, and read its report and the CPU seconds the process
    used (as it says; the wall-clock time it took if it says nothing)."""
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="cpcc-dry-run-") as tmp:
        folder = Path(tmp)
        (folder / "request.json").write_text(json.dumps(request), encoding="utf-8")
        env = {
            **os.environ,
            "DJANGO_SETTINGS_MODULE": settings.SETTINGS_MODULE or SETTINGS,
            "DATABASE_URL": f"sqlite:///{folder / 'copy.sqlite3'}",
            "CPCC_MEDIA_ROOT": str(folder / "media"),
            "CPCC_VAR_DIR": str(settings.VAR_DIR),
            "CPCC_ISOLATE_POOL": "0",
            "CPCC_LOG_LEVEL": "WARNING",
        }
        try:
            done = subprocess.run(
                [sys.executable, "manage.py", "dry_run_copy", str(folder)],
                cwd=settings.BASE_DIR,
                env=env,
                stdin=subprocess.DEVNULL,
                capture_output=True,
                timeout=timeout_s,
                check=False,
            )
        except subprocess.TimeoutExpired:
            raise DryRunFailed(
                f"the simulated copy of the fleet did not answer within {timeout_s:g} s"
            ) from None
        report = folder / "report.json"
        if done.returncode != 0 or not report.exists():
            tail = done.stderr.decode("utf-8", errors="replace")[-2000:]
            logger.error("dry run failed", extra={"exit_status": done.returncode, "stderr": tail})
            raise DryRunFailed(f"the simulated copy of the fleet failed ({done.returncode})")
        found = json.loads(report.read_text(encoding="utf-8"))
        cpu_s = found.get("cpu_s")
        if not isinstance(cpu_s, (int, float)):
            cpu_s = time.monotonic() - started
        return DryRunReport.from_json(found), float(cpu_s)
