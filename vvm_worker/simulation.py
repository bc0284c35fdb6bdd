"""The whole platform in one process on discrete-event time: what ``manage.py simulate`` runs.

The same services run as in the distributed platform (loader, mapper, migrator, steps, the
RVs' control loops); only the dispatcher differs: instead of sending a Celery task to a host's
queue, it puts an event on one priority queue ordered by (simulated time, arrival order).
With ``speed`` 0 the clock jumps from event to event; with ``speed`` N an event at simulated
time t waits until t / N seconds of wall time have passed since the start.
"""

from __future__ import annotations

import contextlib
import heapq
import logging
import math
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from django.conf import settings
from django.db.models import Count, Prefetch, Sum

from fleet.geo import Position
from fleet.models import Flight, Vehicle
from fleet.simulation import SensorField
from missions.models import (
    ENDED_STATUSES,
    Migration,
    StorageDocument,
    Task,
    TaskStatus,
    VirtualVehicle,
)
from missions.readings import map_camera_readings
from vvm_worker.clock import SimulatedClock
from vvm_worker.dispatch import HostRef
from vvm_worker.executor import (
    PlatformSensing,
    RigFleet,
    VehicleRig,
    build_rig,
    write_estimates,
)
from vvm_worker.planning import DEFAULT_PLANNER, make_planner
from vvm_worker.runtime import Runtime
from vvm_worker.scenario import FleetEvent, Scenario, vv_instances
from vvm_worker.services import (
    VVM,
    vv_admit_queued,
    vv_advance,
)
from vvm_worker.services.scenarios import (
    LoadedScenario,
    scenario_apply,
    scenario_event_apply,
    scenario_submit_vv,
)
from vvm_worker.services.service_levels import service_levels_classed, service_levels_report

logger = logging.getLogger("cpcc.simulation")

ProgressFn = Callable[["Progress"], None]
_PROGRESS_EVERY_S = 0.1
# Warm V8 contexts kept by the one runtime every host shares (an isolate is about 1 MB, 1.5
# with a program's heap); a VV beyond them resumes by replay (a new isolate and its journal
# run again), as it would on another host. 2,048 keep every VV of a 1,000-VV run warm (a
# replay costs some 20 times a resumed step) within about 3 GB.
WARM_CONTEXTS = 2048


@dataclass(frozen=True)
class Progress:
    """Where a running simulation is, for a progress bar."""

    time_s: float
    vvs_total: int
    vvs_ended: int
    tasks_done: int
    events: int


class EventQueue:
    """Callbacks ordered by (time, order of scheduling): the same order on every run."""

    def __init__(self, clock: SimulatedClock) -> None:
        self.clock = clock
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = 0

    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        self._seq += 1
        heapq.heappush(self._heap, (max(t_s, self.clock.t), self._seq, fn))

    def call_now(self, fn: Callable[[], None]) -> None:
        self.call_at(self.clock.t, fn)

    def pop(self) -> tuple[float, Callable[[], None]] | None:
        if not self._heap:
            return None
        t, _, fn = heapq.heappop(self._heap)
        return t, fn

    def __len__(self) -> int:
        return len(self._heap)


class _QueueDispatcher:
    def __init__(self, sim: Simulation) -> None:
        self.sim = sim

    def vv_arrived(self, vv_id: uuid.UUID, *, on: HostRef | None = None) -> None:
        self.sim.queue.call_now(lambda: vv_advance(vv_id=vv_id, vvm=self.sim.vvm))

    def vv_wake_later(self, vv_id: uuid.UUID, delay_s: float) -> None:
        self.sim.queue.call_at(
            self.sim.clock.t + max(0.0, delay_s),
            lambda: vv_advance(vv_id=vv_id, vvm=self.sim.vvm),
        )

    def vehicle_changed(self, vehicle_id: int) -> None:
        rig = self.sim.rigs.get(vehicle_id)
        if rig is not None:
            self.sim.queue.call_now(rig.changed())

    def customer_slot_freed(self, customer_id: int) -> None:
        self.sim.queue.call_now(lambda: vv_admit_queued(customer_id=customer_id, vvm=self.sim.vvm))


class Simulation:
    """A scenario run to its end on discrete-event time. Use ``run()`` once."""

    def __init__(
        self,
        scenario: Scenario | None = None,
        *,
        planner: str = DEFAULT_PLANNER,
        seed: int = 1,
        speed: float = 0.0,
        logins: bool = True,
    ) -> None:
        make_planner(planner)  # an unknown name fails here, before anything is loaded
        self.scenario = scenario
        self.planner_name = planner
        self.seed = seed
        self.speed = speed
        self.logins = logins  # a login user for each customer (results kept to look at)
        self.clock = SimulatedClock()
        self.queue = EventQueue(self.clock)
        self.vvm = VVM(
            clock=self.clock,
            dispatcher=_QueueDispatcher(self),
            field=SensorField(seed),
            world_seed=seed,
            runtime=Runtime(max_contexts=WARM_CONTEXTS),
            hosts_share_runtime=True,
        )
        # Every RV's loop runs here: the services ask them, not the database.
        self.fleet = RigFleet(lambda rig, wake: self.queue.call_now(wake))
        self.rigs: dict[int, VehicleRig] = self.fleet.rigs
        self.sensing = PlatformSensing(self.vvm)  # one copy of the SDC for every RV
        self.vvm.local_fleet = self.fleet
        self.loaded: LoadedScenario | None = None
        self.events_run = 0
        self.wall_s = 0.0  # how long `run` took
        self.vv_ids: list[uuid.UUID] = []  # the VVs this run submitted

    # --- set-up --------------------------------------------------------------------------------

    def add_vehicle_loop(self, vehicle: Vehicle, airborne_at: Position | None = None) -> VehicleRig:
        """Give an RV a simulated vehicle and a control loop (its worker, in one process);
        ``airborne_at``: where it starts in the air (its scenario's ``start``)."""
        rig = build_rig(
            vehicle,
            vvm=self.vvm,
            scheduler=self.queue,
            planner=self.planner_name,
            defer_reports=True,
            sensing=self.sensing,
            airborne_at=airborne_at,
        )
        self.fleet.add(rig)
        return rig

    def _fleet_event(self, event: FleetEvent) -> None:
        assert self.loaded is not None
        vehicle = scenario_event_apply(event=event, vvm=self.vvm, on_added=self.add_vehicle_loop)
        self.loaded.vehicles[vehicle.name] = vehicle

    def start(self) -> LoadedScenario:
        """Load the scenario and schedule its VVs and fleet events (``run`` does this too)."""
        self._setup()
        assert self.loaded is not None
        return self.loaded

    def _setup(self) -> None:
        assert self.scenario is not None
        self.loaded = scenario_apply(scenario=self.scenario, logins=self.logins)
        starts = {v.name: v.start for v in self.scenario.vehicles}
        for name, vehicle in self.loaded.vehicles.items():
            self.add_vehicle_loop(vehicle, starts.get(name))
        for spec, name in vv_instances(self.scenario):
            customer = self.loaded.customers[spec.customer]

            def submit(spec: Any = spec, name: str = name, customer: Any = customer) -> None:
                vv = scenario_submit_vv(
                    spec=spec, instance_name=name, customer=customer, vvm=self.vvm, seed=self.seed
                )
                self.vv_ids.append(vv.pk)

            self.queue.call_at(spec.submit_at_s, submit)
        for event in self.scenario.events:
            self.queue.call_at(event.at_s, lambda event=event: self._fleet_event(event))

    # --- running -------------------------------------------------------------------------------

    def run(self, *, progress: ProgressFn | None = None, flights: bool = False) -> dict[str, Any]:
        """Run the scenario until nothing is left to happen; returns the summary (with
        ``flights``: each RV's flights too)."""
        started = time.perf_counter()
        with _no_statement_log():
            if self.loaded is None:
                self._setup()
            self.drain(progress=progress, total=self.vv_count)
            summary = self.summary(flights=flights)
        self.wall_s = time.perf_counter() - started
        return summary

    def speed_line(self, summary: dict[str, Any]) -> str:
        """How fast the run went (wall time, so never part of the summary itself, which is the
        same on every run): tasks done a second of wall time, from loading to the summary."""
        tasks = sum(vv["tasks_done"] for vv in summary["vvs"])
        rate = tasks / self.wall_s if self.wall_s > 0 else 0.0
        return (
            f"simulated {tasks:,} tasks, {len(summary['migrations']):,} migrations and "
            f"{self.events_run:,} events in {self.wall_s:.1f} s of wall time: "
            f"{rate:,.1f} tasks/s"
        )

    @property
    def vv_count(self) -> int:
        return len(vv_instances(self.scenario)) if self.scenario is not None else 0

    def drain(
        self,
        *,
        progress: ProgressFn | None = None,
        total: int = 0,
        until: Callable[[], bool] | None = None,
    ) -> None:
        """Process events until none is left (every VV ended, every RV landed), or until the
        condition ``until`` holds after an event."""
        wall_start = time.monotonic()
        next_report = 0.0
        next_tick = wall_start + settings.CPCC_MAP_TICK_S
        while (until is None or not self._seen(until)) and (item := self.queue.pop()) is not None:
            t, fn = item
            if self.speed > 0:
                delay = wall_start + t / self.speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            self.clock.t = t
            fn()
            self.events_run += 1
            if time.monotonic() >= next_tick:  # the map tick of the RV workers, on wall time
                self._write_estimates()
                next_tick = time.monotonic() + settings.CPCC_MAP_TICK_S
            if progress is not None and time.monotonic() >= next_report:
                progress(self._progress(total))
                next_report = time.monotonic() + _PROGRESS_EVERY_S
        for rig in self.rigs.values():  # the rows say where every RV is now
            rig.store.flush()
        self._write_estimates()
        if progress is not None:
            progress(self._progress(total))

    def _seen(self, until: Callable[[], bool]) -> bool:
        """Whether ``until`` holds, asked of the rows as a reader would see them after a
        map tick (the estimates that wait are written first)."""
        self._write_estimates()
        return until()

    def _write_estimates(self) -> None:
        """When the RVs expect to reach the VVs' next tasks, as their plans last said: one
        statement for the whole fleet (``write_estimates``)."""
        write_estimates([rig.store for rig in self.rigs.values()])

    def _progress(self, total: int) -> Progress:
        mine = VirtualVehicle.objects.filter(pk__in=self.vv_ids)
        return Progress(
            time_s=self.clock.t,
            vvs_total=total,
            vvs_ended=mine.filter(status__in=ENDED_STATUSES).count(),
            tasks_done=Task.objects.filter(vv__in=self.vv_ids, status=TaskStatus.DONE).count(),
            events=self.events_run,
        )

    # --- the summary (DESIGN.md section 5) --------------------------------------------------

    def summary(self, *, flights: bool = False) -> dict[str, Any]:
        """The run's results (DESIGN.md section 5); with ``flights``, each RV's flights under
        "flights" (only then: a summary without it is as it always was)."""
        end = self.clock.t
        vvs = []
        # Three reads for all of them (the VVs, their tasks, their storage), only what the
        # summary shows.
        tasks_shown = (
            Task.objects.select_related("vehicle")
            .only("vv_id", "lat", "lng", "alt", "vehicle__name", "requested_s", "done_s", "status")
            .order_by("q", "index")
        )
        mine = (
            VirtualVehicle.objects.filter(pk__in=self.vv_ids)
            .select_related("customer")
            .only("name", "customer__name", "status", "error", "submitted_s", "finished_s")
            .prefetch_related(
                Prefetch("tasks", queryset=tasks_shown),
                Prefetch("storage", queryset=StorageDocument.objects.order_by("key")),
            )
        )
        for vv in mine.order_by("submitted_s", "customer__name", "name"):
            tasks = [
                {
                    "position": [t.lat, t.lng, t.alt],
                    "vehicle": t.vehicle.name if t.vehicle is not None else None,
                    "requested_s": _r(t.requested_s),
                    "done_s": _r(t.done_s),
                    "status": t.status,
                }
                for t in vv.tasks.all()
            ]
            vvs.append(
                {
                    "name": vv.name,
                    "customer": vv.customer.name,
                    "status": vv.status,
                    "error": vv.error or None,
                    "submitted_s": _r(vv.submitted_s),
                    "finished_s": _r(vv.finished_s),
                    "tasks_done": sum(1 for t in tasks if t["status"] == TaskStatus.DONE),
                    "storage": {d.key: _resolve_images(d.value) for d in vv.storage.all()},
                    "tasks": tasks,
                }
            )
        vehicles = []
        for vehicle in Vehicle.objects.filter(pk__in=list(self.rigs)).order_by("name"):
            driver = self.rigs[vehicle.pk].driver if vehicle.pk in self.rigs else None
            vehicles.append(
                {
                    "name": vehicle.name,
                    "distance_m": _r(driver.distance_m(end)) if driver else 0.0,
                    "tasks_done": vehicle.tasks_done,
                    "flight_s": _r(driver.flight_s(end)) if driver else 0.0,
                }
            )
        migrations = [
            {"vv": vv_name, "from": from_name, "to": to_name, "at_s": _r(at_s)}
            for vv_name, from_name, to_name, at_s in Migration.objects.filter(vv__in=self.vv_ids)
            .order_by("at_s", "id")
            .values_list("vv__name", "from_name", "to_name", "at_s")
        ]
        finished = [v["finished_s"] for v in vvs if v["finished_s"] is not None]
        waits = [
            t["done_s"] - t["requested_s"]
            for v in vvs
            for t in v["tasks"]
            if t["status"] == TaskStatus.DONE and t["done_s"] is not None
        ]
        summary: dict[str, Any] = {
            "makespan_s": max(finished) if finished else 0.0,
            "planner": self.planner_name,
            "vvs": vvs,
            "vehicles": vehicles,
            "migrations": migrations,
            "latency": latency_summary(waits),
        }
        # Only with classes, so that a scenario without any sums up as it always did.
        if service_levels_classed(vv_ids=self.vv_ids):
            summary["service_levels"] = self.service_levels()
        if flights:
            summary["flights"] = self.flights()
        return summary

    def flights(self) -> list[dict[str, Any]]:
        """Each RV's flights in this run, by name: how many, and their time and distance
        (those ended; one still in the air counts, its time and distance not yet)."""
        totals = {
            vehicle_id: (count, flight_s, distance_m)
            for vehicle_id, count, flight_s, distance_m in Flight.objects.filter(
                vehicle_id__in=list(self.rigs)
            )
            .values("vehicle_id")
            .annotate(count=Count("id"), flight_s=Sum("duration_s"), distance_m=Sum("distance_m"))
            .values_list("vehicle_id", "count", "flight_s", "distance_m")
        }
        rows = []
        for pk, name in (
            Vehicle.objects.filter(pk__in=list(self.rigs))
            .order_by("name")
            .values_list("pk", "name")
        ):
            count, flight_s, distance_m = totals.get(pk, (0, None, None))
            rows.append(
                {
                    "vehicle": name,
                    "flights": count,
                    "flight_s": _r(flight_s or 0.0),
                    "distance_m": _r(distance_m or 0.0),
                }
            )
        return rows

    def service_levels(self) -> dict[str, list[dict[str, object]]]:
        """How each class's target was kept in this run: the report of the platform
        (``service_levels_report``) over this run's VVs, per customer and per class."""
        return {
            "customers": [s.as_dict() for s in service_levels_report(vv_ids=self.vv_ids)],
            "classes": [
                s.as_dict() for s in service_levels_report(vv_ids=self.vv_ids, by_customer=False)
            ],
        }


@contextlib.contextmanager
def _no_statement_log() -> Iterator[None]:
    """With DEBUG on, Django formats and keeps every SQL statement: a tenth of a run's time."""
    debug = settings.DEBUG
    settings.DEBUG = False
    try:
        yield
    finally:
        settings.DEBUG = debug


def latency_summary(waits: list[float]) -> dict[str, Any]:
    """How long the tasks read waited from request to reading: count, mean, 95th percentile
    (nearest rank) and maximum, in seconds (0 when no task was read)."""
    if not waits:
        return {"tasks": 0, "mean_s": 0.0, "p95_s": 0.0, "max_s": 0.0}
    ordered = sorted(waits)
    rank = max(0, math.ceil(0.95 * len(ordered)) - 1)
    return {
        "tasks": len(ordered),
        "mean_s": _r(sum(ordered) / len(ordered)),
        "p95_s": _r(ordered[rank]),
        "max_s": _r(ordered[-1]),
    }


def _r(value: float | None) -> float | None:
    """Times and distances in the summary, to the millisecond and millimetre."""
    return None if value is None else round(value, 3)


def _resolve_images(value: Any) -> Any:
    """Camera readings in the summary name their image by its absolute file path."""
    media = Path(settings.MEDIA_ROOT)
    return map_camera_readings(
        value, lambda reading: {**reading, "image": str(media / reading["image"])}
    )
