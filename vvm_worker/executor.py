"""The task executor on the platform: an RV's control loop (``vvm_worker.control``) with its
work in the database, its sensors read for the VVs, and the one builder of an RV's loop that
``simulate`` and the RV workers share.

The database store keeps what the loop asks again and again (the RV's open tasks and its
status) until it is told that they changed (``VehicleRig.changed``: the dispatcher's
``vehicle_changed``, a sweep) or finds out (a task completed by someone else): a plan reads
nothing that has not changed.
"""

from __future__ import annotations

import datetime as dt
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from django.conf import settings
from django.db import transaction
from django.db.models import F

from accounts.models import Customer
from fleet.airspace import Airspace
from fleet.driving import Driver, Sample, SensorFailure, SensorRead
from fleet.geo import Position, within_m
from fleet.kinds import limits_of
from fleet.models import Driver as DriverKind
from fleet.models import Flight, SensorType, Vehicle, VehicleStatus
from fleet.plugins import SensorPlugin, plugin_class
from fleet.simulation import SimVehicle
from fleet.simulation import VehicleSpec as KinematicSpec
from fleet.sources import FIELD, PLUGIN, SensorSource, source_for
from missions.models import ACTIVE_STATUSES, Task, VirtualVehicle
from vvm_worker.control import (
    REACH_SLACK_M,
    Area,
    ControlLoop,
    Landing,
    LoopConfig,
    LoopTask,
    OperatorCommand,
    PlanElsewhere,
    Scheduler,
    VehicleState,
)
from vvm_worker.level_figures import NO_CLASS_TERMS, ClassTerms
from vvm_worker.planning import Planner, TravelTime, make_planner
from vvm_worker.sensing import read_sensors, vehicle_reading
from vvm_worker.services import (
    VVM,
    task_complete,
    vehicle_check_maintenance,
    vehicle_command_take,
    vehicle_record_flights,
    vehicle_record_state,
    vehicle_record_track,
    vehicle_set_status,
)
from vvm_worker.services.base import LocalRV, Settled
from vvm_worker.services.flight_logs import flight_log_save
from vvm_worker.services.routing import fleet_airspace, planned_order
from vvm_worker.services.store import LandingRow, TakeOffRow, vehicle_tasks
from vvm_worker.services.waiting import vvs_record_next_task_eta

logger = logging.getLogger("cpcc.flights")

_SDC_TTL_S = 10.0
# An estimate of when an RV reaches a VV's task is written again when it moves by more.
ESTIMATE_SLACK_S = 1.0


def _loop_task(task: Task, terms: ClassTerms) -> LoopTask:
    return LoopTask(
        id=task.pk,
        position=Position(task.lat, task.lng, task.alt),
        tolerance_m=task.tolerance_m,
        requested_s=task.requested_s,
        sensors=tuple(task.sensors),
        vv=task.vv_id,
        # The tasks of one request (an executeAll batch) share a group.
        group=f"{task.vv_id}:{task.q}",
        weight=terms.weight,
        deadline_s=terms.deadline(task.requested_s),
        service_class=terms.class_id,
    )


def _request_of(task: LoopTask) -> int | None:
    """The VV's request a task of the loop belongs to, as its group says (``_loop_task``)."""
    if task.group is None:
        return None
    _, _, q = task.group.rpartition(":")
    return int(q) if q.isdigit() else None


def _terms_held(task: Task) -> ClassTerms | None:
    """The terms of the task's VV's service class as its VV (the one its caller holds, read
    with its customer and class) has them, or None if it was not read with them."""
    if not Task.vv.is_cached(task):
        return None
    vv = task.vv
    if not VirtualVehicle.customer.is_cached(vv):
        return None
    customer = vv.customer
    if customer.service_class_id is None:
        return NO_CLASS_TERMS
    if not Customer.service_class.is_cached(customer):
        return None
    service_class = customer.service_class
    return ClassTerms.of(service_class.weight, service_class.p95_s, service_class.pk)


def write_estimates(stores: Sequence[DatabaseStore]) -> None:
    """The estimates that wait in these RVs' stores (see ``DatabaseStore.estimated``), in one
    statement for all of them; those whose VV another transaction holds wait in their store
    for the next time (unless a newer estimate replaces them)."""
    taken = [(store, store.take_estimates()) for store in stores]
    etas = {vv: eta_s for _, some in taken for vv, eta_s in some.items()}
    if not etas:
        return
    left = vvs_record_next_task_eta(etas=etas)
    for store, some in taken:
        store.keep_estimates({vv: left[vv] for vv in some if vv in left})


class DatabaseStore:
    """An RV's work as the platform keeps it (``vvm_worker.control.Store``)."""

    def __init__(
        self, *, vehicle_id: int, vvm: VVM, ticks: bool = False, defer_reports: bool = False
    ) -> None:
        self.vehicle_id = vehicle_id
        self.vvm = vvm
        # ``ticks`` (the RV workers): the host calls ``write_waiting`` at every map tick, so a
        # report that does not move the vehicle may wait for it (see ``record_state``).
        self.ticks = ticks
        # ``defer_reports`` (``simulate``, where the process is the platform and the services
        # ask the loops, not the rows): the reports wait, and are written (``settle``) by the
        # transaction that next changes who is aboard, before it does (an answer here, a VV
        # boarding or leaving), or by ``flush``: the ends of the legs flown, for the track of
        # the VVs aboard, then the row as of the latest report.
        self.defer_reports = defer_reports
        self._points: list[VehicleState] = []
        self._latest: VehicleState | None = None
        self._tasks_done = 0  # served since the row was written
        # What `settle` wrote, for the fleet to take back if the transaction rolls back.
        self.settled_log: list[tuple[DatabaseStore, _Waiting]] | None = None
        self._tasks: list[LoopTask] | None = None
        self._added: list[Task] = []  # put on the list since (see `add`)
        self._terms: dict[Any, ClassTerms] = {}  # each VV's service class terms, as last read
        self._status: str | None = None
        self.status_reason = ""  # why the status is what it is, as read with it
        # An operator's command that waits for the RV, as read with the status: (command,
        # when it was asked), the fence that takes it exactly once.
        self._command: tuple[str, Any] | None = None
        self._aboard: list[dict[str, Any]] = []
        # Where the vehicle stopped, to be recorded with the first task it serves there (one
        # transaction), or on its own by the next record.
        self._arrival: VehicleState | None = None
        # A report that did not move the vehicle (a new plan, a phase): it waits for the next
        # write, which supersedes it, or for the host's next ``write_waiting`` (a map tick).
        self._waiting: VehicleState | None = None
        # When the loop last said the vehicle reaches each VV's next task (see `estimated`),
        # and, with ``ticks``, the estimates that wait for the map tick to be written.
        self._estimates: dict[Any, float] = {}
        self._etas_waiting: dict[Any, float] = {}
        # The take-offs the loop reported (platform clock, the odometers then) and the ends
        # of flights (``Landing``), written with the next write of the row or of the track
        # (in its unit of work), which reads the pilot on duty then.
        self._take_offs: list[_TakeOff] = []
        self._landings: list[Landing] = []

    def changed(self) -> None:
        """The RV's tasks or status may have changed: read them again when next asked."""
        self._tasks = None
        self._status = None
        self._added = []

    def add(self, tasks: Sequence[Task]) -> None:
        """These tasks were put on the RV's list (saved by the end of the transaction that
        put them there): known without reading them again."""
        if self._tasks is not None:
            self._added.extend(tasks)

    def open_tasks(self) -> Sequence[LoopTask]:
        if self._tasks is not None and any(t.pk is not None for t in self._added):
            # (One not saved yet is kept for later; the transaction saves it.)
            saved = [t for t in self._added if t.pk is not None]
            self._terms.update(
                (t.vv_id, terms) for t in saved if (terms := _terms_held(t)) is not None
            )
            terms_of = self._class_terms({t.vv_id for t in saved})
            added = [_loop_task(t, terms_of.get(t.vv_id, NO_CLASS_TERMS)) for t in saved]
            self._added = [t for t in self._added if t.pk is None]
            have = {t.id for t in self._tasks}
            self._tasks = sorted(
                [*self._tasks, *(t for t in added if t.id not in have)],
                key=lambda t: (t.requested_s, t.id),
            )
        if self._tasks is None:
            self._tasks = []
            for row in vehicle_tasks(self.vehicle_id):
                pk, lat, lng, alt, tolerance_m, requested_s, sensors, vv_id, q, *of_class = row
                terms = ClassTerms.of(*of_class)
                self._terms[vv_id] = terms
                self._tasks.append(
                    LoopTask(
                        id=pk,
                        position=Position(lat, lng, alt),
                        tolerance_m=tolerance_m,
                        requested_s=requested_s,
                        sensors=tuple(sensors),
                        vv=vv_id,
                        group=f"{vv_id}:{q}",
                        weight=terms.weight,
                        deadline_s=terms.deadline(requested_s),
                        service_class=terms.class_id,
                    )
                )
        return self._tasks

    def _class_terms(self, vv_ids: set[Any]) -> dict[Any, ClassTerms]:
        """The service class terms of each of these VVs' customers (``NO_CLASS_TERMS``
        without a class): those not known yet in one query."""
        unknown = vv_ids - self._terms.keys()
        if unknown:
            for vv_id, *of_class in VirtualVehicle.objects.filter(pk__in=unknown).values_list(
                "pk",
                "customer__service_class__weight",
                "customer__service_class__p95_s",
                "customer__service_class_id",
            ):
                self._terms[vv_id] = ClassTerms.of(*of_class)
        return self._terms

    def status(self) -> str:
        if self._status is None:
            status, reason, command, asked, taken = Vehicle.objects.values_list(
                "status", "status_reason", "command", "command_requested", "command_taken"
            ).get(pk=self.vehicle_id)
            self._status, self.status_reason = str(status), reason
            pending = command and asked is not None and taken is None
            self._command = (command, asked) if pending else None
        return self._status

    def take_command(self) -> OperatorCommand | None:
        self.status()
        if self._command is None:
            return None
        (command, asked), self._command = self._command, None
        if not vehicle_command_take(vehicle_id=self.vehicle_id, command=command, asked=asked):
            self._status = None  # another command came meanwhile: read it with the status
            return None
        return OperatorCommand(command, asked.isoformat())

    def set_status(self, status: str, *, expected: str | None = None, reason: str = "") -> None:
        vehicle_set_status(
            vehicle=Vehicle(pk=self.vehicle_id),
            status=VehicleStatus(status),
            vvm=self.vvm,
            reason=reason,
            expected=None if expected is None else VehicleStatus(expected),
        )
        self._status = None

    def complete(self, task: LoopTask, readings: list[dict[str, Any]], now_s: float) -> None:
        self._answer(task, readings, now_s)

    def fail(self, task: LoopTask, reason: str, now_s: float) -> None:
        self._answer(task, [], now_s, failure=reason)

    def _answer(
        self,
        task: LoopTask,
        readings: list[dict[str, Any]],
        now_s: float,
        failure: str | None = None,
    ) -> None:
        log = self.settled_log
        if log is not None:
            log.clear()  # what was settled before is committed
        arrival, self._arrival = self._arrival, None
        if self._tasks is not None:  # what the mapper sees of this RV meanwhile
            self._tasks = [t for t in self._tasks if t.id != task.id]
        try:
            done = task_complete(
                task_id=task.id,
                readings=readings,
                vvm=self.vvm,
                vehicle_id=self.vehicle_id,
                vv_id=task.vv,
                arrival=arrival,
                failure=failure,
                q=_request_of(task),
            )
        except BaseException:
            self._arrival = arrival  # rolled back with the answer: still to be recorded
            self._tasks = None
            for store, waiting in reversed(log or []):
                store.unsettle(waiting)
            raise
        if not done:  # no longer this RV's (cancelled, moved on): read the tasks again
            self._tasks = None
            if arrival is not None:
                self._write(arrival, moved=True)

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        # (Each once, if the work is done again.)
        if state.took_off_s is not None and all(t.t_s != state.took_off_s for t in self._take_offs):
            self._take_offs.append(_TakeOff(state.took_off_s, state.distance_m, state.flight_s))
        if state.landing is not None and state.landing not in self._landings:
            self._landings.append(state.landing)
        if self.defer_reports:
            if moved:
                self._points.append(state)
            self._latest = state
            return
        if not moved and self.ticks:
            self._waiting = state
            return
        if self._arrival is not None:  # no task was served where it stopped
            arrival, self._arrival = self._arrival, None
            self._write(arrival, moved=True)
        # Where it stops to serve, the arrival goes with the first answer, in its transaction
        # (the arrival's track points refer to every VV aboard, which other processes may hold:
        # they hold them FOR NO KEY UPDATE, which such references do not wait for).
        if moved and self._serves_here(state.position):
            self._arrival = state
            return
        self._write(state, moved=moved)

    def estimated(self, etas: dict[Any, float]) -> None:
        """The loop's plan: when the vehicle expects to reach each VV's next task (by VV).
        Only the estimates that moved by more than ESTIMATE_SLACK_S are written: a plan that
        keeps its target (most of them) writes nothing, a new target one VV's. With ``ticks``
        they wait for the host's map tick (``write_waiting``), with ``defer_reports`` for the
        simulation's (``write_estimates``): an estimate is read by people, and the plans of a
        busy RV change it many times a second."""
        told = self._estimates
        changed = {
            vv: eta_s
            for vv, eta_s in etas.items()
            if vv not in told or abs(told[vv] - eta_s) > ESTIMATE_SLACK_S
        }
        self._estimates = {vv: changed.get(vv, told.get(vv, eta_s)) for vv, eta_s in etas.items()}
        self._etas_waiting.update(changed)
        if not self.ticks and not self.defer_reports:
            write_estimates([self])

    def take_estimates(self) -> dict[Any, float]:
        """The estimates that wait to be written (see ``write_estimates``), taken out."""
        etas, self._etas_waiting = self._etas_waiting, {}
        return etas

    def keep_estimates(self, etas: dict[Any, float]) -> None:
        """Estimates taken but not written: they wait again, unless a newer one replaced
        them meanwhile."""
        if etas:
            self._etas_waiting = {**etas, **self._etas_waiting}

    def write_waiting(self) -> None:
        """Write the report that waits, if any (the host's map tick: a row is never more than
        a tick behind what its loop said). Where it stopped to serve a task waits for the
        answer, which writes it. Then the take-offs and landings that wait (none, mostly: they
        go with a report) and the estimates that wait (see ``estimated``)."""
        if self._waiting is not None:
            self._write(self._waiting, moved=False)
        elif self._take_offs or self._landings:
            take_offs, landings = self._take_offs, self._landings
            vehicle_record_flights(
                vehicle_id=self.vehicle_id,
                take_offs=self._take_off_rows(take_offs),
                landings=self._landing_rows(landings),
            )
            self._take_offs = self._take_offs[len(take_offs) :]
            self._landings = self._landings[len(landings) :]
            self._keep_logs(landings)
        write_estimates([self])

    def seen_aboard(self, vvs: list[dict[str, Any]]) -> None:
        """The VVs aboard as the host read them for the map (see ``read_aboard``)."""
        self._aboard = vvs

    def settle(self, *, tasks_done: int = 0) -> Settled:
        """Write the track points, take-offs and landings that wait (``defer_reports``), in
        the caller's transaction, and count ``tasks_done`` more tasks (written with the row);
        where the RV last said it is (None: it has said nothing since the row was written)."""
        take_offs, self._take_offs = self._take_offs, []
        landings, self._landings = self._landings, []
        if take_offs or landings:
            vehicle_record_flights(
                vehicle_id=self.vehicle_id,
                take_offs=self._take_off_rows(take_offs),
                landings=self._landing_rows(landings),
            )
            self._keep_logs(landings)
        if self._points:
            points, self._points = self._points, []
            vehicle_record_track(
                vehicle_id=self.vehicle_id, points=[(p.t_s, p.position) for p in points]
            )
            if self.settled_log is not None:
                self.settled_log.append((self, _Waiting(points, tasks_done, take_offs, landings)))
        elif (tasks_done or take_offs or landings) and self.settled_log is not None:
            self.settled_log.append((self, _Waiting([], tasks_done, take_offs, landings)))
        self._tasks_done += tasks_done
        return Settled(None if self._latest is None else self._latest.position)

    def unsettle(self, waiting: _Waiting) -> None:
        """What ``settle`` wrote was rolled back: it waits again."""
        self._points = [*waiting.points, *self._points]
        self._tasks_done -= waiting.tasks_done
        self._take_offs = [*waiting.take_offs, *self._take_offs]
        self._landings = [*waiting.landings, *self._landings]

    def _date(self, t_s: float) -> dt.datetime:
        """The date of a time of the platform clock (its epoch)."""
        return dt.datetime.fromtimestamp(self.vvm.clock.epoch_ms(t_s) / 1000, tz=dt.UTC)

    def _take_off_rows(self, take_offs: Sequence[_TakeOff]) -> list[TakeOffRow]:
        return [TakeOffRow(t.t_s, self._date(t.t_s), t.distance_m, t.flight_s) for t in take_offs]

    def _landing_rows(self, landings: Sequence[Landing]) -> list[LandingRow]:
        return [
            LandingRow(
                took_off_s=x.took_off_s,
                t_s=x.t_s,
                at=self._date(x.t_s),
                how=x.how,
                distance_m=x.distance_m,
                flight_s=x.flight_s,
                max_alt_m=x.max_alt_m,
                battery_start_pct=x.battery_start_pct,
                battery_end_pct=x.battery_end_pct,
                track=x.track,
            )
            for x in landings
        ]

    def flush(self) -> None:
        """Write the reports that wait (see ``defer_reports``): track points, then the row."""
        if self._latest is not None:
            latest = self._latest
            with transaction.atomic():
                self.settle()  # (the take-offs too)
                vehicle_record_state(
                    vehicle_id=self.vehicle_id, state=latest, tasks_done=self._tasks_done
                )
            self._latest, self._tasks_done = None, 0
        elif self._tasks_done:
            Vehicle.objects.filter(pk=self.vehicle_id).update(
                tasks_done=F("tasks_done") + self._tasks_done
            )
            self._tasks_done = 0
        if self._arrival is not None:
            arrival, self._arrival = self._arrival, None
            self._write(arrival, moved=True)

    def _serves_here(self, here: Position) -> bool:
        """Whether the loop is about to serve an open task here (it records its arrival
        first): then the record goes with the first answer."""
        return any(
            within_m(here, t.position, t.tolerance_m + REACH_SLACK_M) for t in self.open_tasks()
        )

    def _write(self, state: VehicleState, *, moved: bool) -> None:
        self._waiting = None  # said by this report, or by an earlier one than this
        # The end of a straight leg is on the track of every VV aboard; the take-offs and
        # landings since the last write go in the same commit (cleared once it is done: work
        # redone after an outage writes them again).
        take_offs, landings = self._take_offs, self._landings
        vehicle_record_state(
            vehicle_id=self.vehicle_id,
            state=state,
            track_aboard=moved,
            take_offs=self._take_off_rows(take_offs),
            landings=self._landing_rows(landings),
        )
        self._take_offs = self._take_offs[len(take_offs) :]
        self._landings = self._landings[len(landings) :]
        self._keep_logs(landings)

    def _keep_logs(self, landings: Sequence[Landing]) -> None:
        """Once the landings just written commit: the RV's maintenance looked at again
        (``vehicle_check_maintenance``: what the flights made due grounds it), and the
        telemetry log its driver recorded of each flight (a MAVLink RV's; a simulated RV's is
        made from the flight's track when someone asks for it), through Django's storage
        (``flight_log_save``). Not in ``simulate`` (``defer_reports``: its database is thrown away). A log that cannot be
        kept is logged and left out; the flight stays recorded."""
        if self.defer_reports or not landings:
            return
        landed = list(landings)
        transaction.on_commit(lambda: self._save_logs(landed), robust=True)

    def _save_logs(self, landings: Sequence[Landing]) -> None:
        # What the flight makes due (flight hours, flights, battery cycles) may ground the RV.
        vehicle_check_maintenance(vehicle_id=self.vehicle_id, vvm=self.vvm)
        for landing in landings:
            if landing.log is None:
                continue
            flight = Flight.objects.filter(
                vehicle_id=self.vehicle_id, started_s=landing.took_off_s
            ).first()
            if flight is None:
                landing.log.close()
                continue
            try:
                with landing.log as log:
                    flight_log_save(flight=flight, data=log)
            except (OSError, ValueError):
                logger.exception(
                    "flight %s: its log could not be kept", flight.pk, extra={"flight": flight.pk}
                )

    def area(self) -> Area:
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        return Area(vehicle.area_polygon, vehicle.min_altitude_m, vehicle.max_altitude_m)

    def aboard(self) -> list[dict[str, Any]]:
        return self._aboard


def read_aboard(vehicle_ids: Sequence[int]) -> dict[int, list[dict[str, Any]]]:
    """The VVs aboard these RVs, for the live map: one read for all of them."""
    aboard: dict[int, list[dict[str, Any]]] = {pk: [] for pk in vehicle_ids}
    rows = (
        VirtualVehicle.objects.filter(host_rv_id__in=vehicle_ids, status__in=ACTIVE_STATUSES)
        .order_by("submitted_s", "id")
        .values_list("host_rv_id", "pk", "name", "customer_id")
    )
    for vehicle_id, pk, name, customer_id in rows:
        aboard[vehicle_id].append({"id": str(pk), "name": name, "customer": customer_id})
    return aboard


@dataclass(frozen=True)
class _TakeOff:
    """A take-off the loop reported: when (platform clock) and the odometers then."""

    t_s: float
    distance_m: float
    flight_s: float


@dataclass(frozen=True)
class _Waiting:
    """What one ``settle`` of an RV wrote or counted: the ends of legs, tasks served, its
    take-offs and landings."""

    points: list[VehicleState]
    tasks_done: int
    take_offs: list[_TakeOff] = field(default_factory=list)
    landings: list[Landing] = field(default_factory=list)


class PlatformSensing:
    """The readings of a task's sensors from the VVM's sensor world (``vvm_worker.control.
    Sensing``), by the SDC entries the sensors name."""

    def __init__(self, vvm: VVM) -> None:
        self.vvm = vvm
        self._sdc: tuple[float, dict[str, dict[str, Any]]] | None = None

    def __call__(
        self, task: LoopTask, position: Position, now_s: float, battery: float | None
    ) -> list[dict[str, Any]]:
        return self.read(task.sensors, position, now_s, battery)

    def read(
        self, names: Sequence[str], position: Position, now_s: float, battery: float | None
    ) -> list[dict[str, Any]]:
        catalog = self.catalog()
        return read_sensors(
            field=self.vvm.field,
            sensors=[catalog[name] for name in names],
            position=position,
            time_s=now_s,
            epoch_ms=self.vvm.clock.epoch_ms(now_s),
            battery_fraction=battery,
            seed=self.vvm.world_seed,
        )

    def catalog(self) -> dict[str, dict[str, Any]]:
        # The SDC changes rarely; read it again now and then, not at every stop.
        now = time.monotonic()
        if self._sdc is None or now - self._sdc[0] > _SDC_TTL_S:
            self._sdc = (now, {s.name: s.as_catalog_entry() for s in SensorType.objects.all()})
        return self._sdc[1]


class VehicleSensing:
    """The readings of one RV's sensors, each from its source (``fleet.sources``): the
    simulated field (``PlatformSensing``), the vehicle itself through its driver (telemetry,
    a companion's named values, its camera), or a plug-in on the vehicle's own computer. A
    reading that does not come raises SensorFailure: the task's error."""

    def __init__(
        self,
        field: PlatformSensing,
        *,
        driver: Driver,
        sources: dict[str, SensorSource],
    ) -> None:
        self.field = field
        self.driver = driver
        self.clock = field.vvm.clock
        self.sources: dict[str, SensorSource] = {}
        self.plugins: dict[str, SensorPlugin] = {}
        self.configure(sources)

    def configure(self, sources: dict[str, SensorSource]) -> None:
        """Read the sensors from these sources from now on: one plug-in instance per sensor
        that names one, made now (one that cannot be loaded or refuses its options raises
        with the reason, and nothing changes); those no longer named are closed."""
        plugins = {
            name: self.plugins[name]
            if self.sources.get(name) == source
            else plugin_class(source.plugin)(**source.options)
            for name, source in sources.items()
            if source.source == PLUGIN
        }
        for name, plugin in self.plugins.items():
            if plugins.get(name) is not plugin:
                plugin.close()
        self.sources, self.plugins = sources, plugins

    def __call__(
        self, task: LoopTask, position: Position, now_s: float, battery: float | None
    ) -> list[dict[str, Any]]:
        if not self.sources:  # every reading from the field, as ever
            return self.field(task, position, now_s, battery)
        catalog = self.field.catalog()
        readings = []
        for name in task.sensors:
            entry = catalog[name]
            source = source_for(self.sources, name)
            if source.source == FIELD:
                readings.extend(self.field.read([name], position, now_s, battery))
                continue
            if source.source == PLUGIN:
                sample = self._plugin_sample(name, source, now_s)
            else:
                sample = self.driver.read_sensor(
                    SensorRead(
                        sensor=name,
                        kind=str(entry["kind"]),
                        params=entry.get("params") or {},
                        source=source.source,
                        name=source.name,
                        since_s=now_s,
                        timeout_s=source.timeout_s,
                    )
                )
            readings.append(vehicle_reading(entry, sample))
        return readings

    def _plugin_sample(self, name: str, source: SensorSource, now_s: float) -> Sample:
        """A plug-in's reading, with where the vehicle was and the time it was taken."""
        try:
            fields = self.plugins[name].read(source.timeout_s)
        except SensorFailure:
            raise
        except Exception as exc:  # a third-party plug-in's own error: its type and words
            raise SensorFailure(
                "the sensor's plug-in failed", where=f"{source.plugin}: {exc!r}"
            ) from exc
        now = self.clock.now_s()
        return Sample(
            fields=fields, epoch_ms=self.clock.epoch_ms(now), position=self.driver.position_at(now)
        )

    def close(self) -> None:
        for plugin in self.plugins.values():
            plugin.close()


@dataclass
class VehicleRig:
    """One RV as a host runs it: its driver, its store, its sensors and its control loop."""

    vehicle_id: int
    name: str
    driver: Driver
    store: DatabaseStore
    loop: ControlLoop
    sensing: VehicleSensing
    planner_for: Callable[[Airspace], Planner]  # a new planner of the RV's kind

    def fly_in(self, airspace: Airspace) -> None:
        """The provider's no-fly zones are now these: the loop flies around them and its
        planner (a new one, with the old one's state) weighs the ways around them."""
        if airspace is self.loop.airspace:
            return
        planner = self.planner_for(airspace)
        planner.restore(self.loop.planner.state())
        self.loop.planner = planner
        self.loop.airspace = airspace

    def changed(self) -> Callable[[], None]:
        """The RV's tasks or status were just changed: forget what the store read, and the
        loop's wake-up to run (see ``ControlLoop.changed``)."""
        self.store.changed()
        return self.loop.changed()


class RigFleet:
    """The RVs whose loops run in this process, as the services ask and tell them
    (``vvm_worker.services.base.LocalFleet``). ``wake`` runs a rig's wake-up where its loop
    runs (the discrete-event queue, the host thread)."""

    def __init__(
        self, wake: Callable[[VehicleRig, Callable[[], None]], None], *, alone: bool = True
    ) -> None:
        self.rigs: dict[int, VehicleRig] = {}
        self._wake = wake
        # Alone (`simulate`): every change of an RV is made in this process, so what its loop
        # knows is what its row says. Otherwise another process may have changed its status
        # a moment ago (its message still on the way): the mapper reads the statuses.
        self.alone = alone
        self._settled: list[tuple[DatabaseStore, _Waiting]] = []

    def live(self, vehicle_id: int, *, route: bool = True) -> LocalRV | None:
        rig = self.rigs.get(vehicle_id)
        if rig is None:
            return None
        store, state = rig.store, rig.loop.last_state
        if state is None:  # it has reported nothing yet: its row says where it is
            return None
        tasks = store.open_tasks() if route else ()
        planned = planned_order([(t.id, t.position) for t in tasks], state.planner_state)
        return LocalRV(
            status=store.status() if self.alone else None,
            position=state.position,
            route=planned,
            classes=tuple(t.service_class for t in tasks),
        )

    def add(self, rig: VehicleRig) -> None:
        self.rigs[rig.vehicle_id] = rig
        rig.store.settled_log = self._settled

    def settle(self, vehicle_id: int, *, tasks_done: int = 0) -> Settled | None:
        rig = self.rigs.get(vehicle_id)
        if rig is None or not rig.store.defer_reports:
            return None
        return rig.store.settle(tasks_done=tasks_done)

    def assigned(self, vehicle_id: int, tasks: Sequence[Any]) -> bool:
        rig = self.rigs.get(vehicle_id)
        if rig is None:
            return False
        rig.store.add(tasks)
        self._wake(rig, rig.loop.changed())
        return True


# With time acceleration 0 ("instant flights") a simulated vehicle flies this much faster.
INSTANT = 1e6


def time_scale(vehicle: Vehicle, speed: float) -> float:
    """How much faster than real time the vehicle's worker takes it to fly: a simulated
    vehicle at the worker's ``speed`` (CPCC_SIM_SPEED; 0: instant), which shortens its flights
    (distances stay right), its battery, charging and standby with them; a MAVLink vehicle
    flies as fast as it flies, whatever the speed (its arrivals, battery and charge are
    what it reports)."""
    if vehicle.driver == DriverKind.MAVLINK:
        return 1.0
    return INSTANT if speed <= 0 else speed


def kinematics(vehicle: Vehicle, *, scale: float = 1.0) -> KinematicSpec:
    """The vehicle's kinematics, ``scale`` times faster (time acceleration of a simulated
    vehicle: distances stay right, flights, turns and the battery's endurance shorten)."""
    turn_rate_dps = vehicle.turn_rate_dps or limits_of(vehicle.kind).turn_rate_dps
    return KinematicSpec(
        max_speed_mps=vehicle.max_speed_mps * scale,
        climb_rate_mps=vehicle.climb_rate_mps * scale,
        battery_s=None if vehicle.battery_s is None else vehicle.battery_s / scale,
        kind=vehicle.kind,
        dive_rate_mps=None if vehicle.dive_rate_mps is None else vehicle.dive_rate_mps * scale,
        turn_rate_dps=None if turn_rate_dps is None else turn_rate_dps * scale,
    )


def build_rig(
    vehicle: Vehicle,
    *,
    vvm: VVM,
    scheduler: Scheduler,
    planner: str,
    scale: float = 1.0,
    driver: Driver | None = None,
    plan_time_limit_s: float | None = None,
    live: bool = False,
    ticks: bool = False,
    defer_reports: bool = False,
    sensing: PlatformSensing | None = None,
    wake_defers_to_arrival: bool = False,
    plan_elsewhere: PlanElsewhere | None = None,
    airborne_at: Position | None = None,
) -> VehicleRig:
    """An RV's control loop over the database: for ``simulate`` (one per RV, one queue) and
    for the RV workers (real time). ``driver``: the vehicle's (a MAVLink autopilot), else a
    simulated vehicle with ``kinematics(vehicle, scale=scale)``, landed at its depot or, with
    ``airborne_at``, hovering there (a scenario's vehicle that starts in the air)."""
    spec = kinematics(vehicle, scale=scale)
    if driver is None:
        sim = SimVehicle(spec, vehicle.depot, now_s=vvm.clock.now_s())
        if airborne_at is not None:
            sim.hover_at(airborne_at, vvm.clock.now_s())
        driver = sim
    store = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm, ticks=ticks, defer_reports=defer_reports)
    readings = VehicleSensing(
        sensing or PlatformSensing(vvm), driver=driver, sources=vehicle.parsed_sources()
    )

    def planner_for(airspace: Airspace) -> Planner:
        return make_planner(
            planner,
            travel_time=TravelTime(spec.max_speed_mps, spec.climb_rate_mps, spec.dive_rate_mps),
            time_limit_s=plan_time_limit_s,
            airspace=airspace,
        )

    airspace = fleet_airspace()
    loop = ControlLoop(
        name=vehicle.name,
        driver=driver,
        planner=planner_for(airspace),
        airspace=airspace,
        store=store,
        scheduler=scheduler,
        clock=vvm.clock.now_s,
        sensing=readings,
        config=LoopConfig(
            battery_s=spec.battery_s,
            reserve=settings.CPCC_BATTERY_RESERVE,
            recharge_s=settings.CPCC_RECHARGE_S / scale,
            resume=settings.CPCC_BATTERY_RESUME,
            standby_s=settings.CPCC_STANDBY_S / scale,
            live=live,
            wake_defers_to_arrival=wake_defers_to_arrival,
        ),
        on_estimates=store.estimated,
        plan_elsewhere=plan_elsewhere,
    )
    return VehicleRig(vehicle.pk, vehicle.name, driver, store, loop, readings, planner_for)
