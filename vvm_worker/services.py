"""The virtual vehicle monitor (VVM): loader, vehicle mapper, migrator and VV steps.

Every function here changes state in one transaction and then tells the dispatcher which host
must act next (DESIGN.md section 3). A VV moves through its life like this:

- ``vv_submit`` queues it; ``vv_admit_queued`` starts as many as the customer's quota of
  parallel VVs allows, each on a ground station (the loader).
- ``vv_advance`` is what the host holding a VV does with it: run the program to its next
  blocking call (a *step*, by replay of the journal), then route the pending task: keep it on
  this RV, migrate to an RV that can serve it, park on a ground station while only RVs in
  maintenance could, or, on a ground station, reject it so the program gets a
  TaskRejectedError. A VV that ends goes back to a ground station.
- ``task_complete`` records the readings an RV took as the answer in the VV's journal and
  resumes the VV on that RV.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import logging
import secrets
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from functools import lru_cache
from typing import Any, overload

from django.conf import settings
from django.db import transaction
from django.db.models import Count, F, Q, QuerySet, TextField
from django.db.models.functions import Cast
from shapely.geometry import Polygon

from accounts.models import Customer
from accounts.selectors import customer_catalog, customer_limits
from fleet.geo import Position, distance_m
from fleet.models import GroundStation, Vehicle, VehicleStatus
from fleet.simulation import SensorField
from missions.models import (
    ACTIVE_STATUSES,
    ENDED_STATUSES,
    HostKind,
    JournalEntry,
    LogEntry,
    Migration,
    StorageDocument,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from vvm_worker.clock import Clock
from vvm_worker.dispatch import Dispatcher
from vvm_worker.mapping import MapDecision, VehicleCaps, map_task
from vvm_worker.runtime import (
    ErrorKind,
    Outcome,
    PendingRequest,
    Runtime,
    StepInput,
    StepResult,
    SyntaxProblem,
    TaskRequest,
    VVError,
    answer_part,
    answer_reject,
    answer_task,
    check_syntax,
)

logger = logging.getLogger("cpcc.vvm")

# Steps one host runs for one VV before it lets other work go first (rejected tasks in a row).
MAX_STEPS_PER_ADVANCE = 50


@dataclass
class VVM:
    """What the services need from the process they run in: the clock, who to tell what to
    do next, the sensor world, and the VV runtime with its warm contexts."""

    clock: Clock
    dispatcher: Dispatcher
    field: SensorField
    world_seed: int = 0
    runtime: Runtime = dataclass_field(default_factory=Runtime)
    # Distributed platform: an RV whose worker has not reported for this long takes no work.
    # None in `simulate`, where every RV's loop runs in the same process.
    lease_s: float | None = None


class ProgramRejected(ValueError):
    """A program that cannot be accepted (a syntax error), with where the problem is."""

    def __init__(self, problem: SyntaxProblem) -> None:
        super().__init__(str(problem))
        self.problem = problem


# --- submission and admission (the loader) ---------------------------------------------------


def vv_submit(
    *,
    customer: Customer,
    name: str,
    program: str,
    vvm: VVM,
    seed: int | None = None,
    vv_id: uuid.UUID | None = None,
    refuse_syntax_errors: bool = True,
    admit: bool = True,
) -> VirtualVehicle:
    """Queue a new VV for the customer and, with ``admit``, start it if the quota allows.

    Raises ProgramRejected for a syntax error unless ``refuse_syntax_errors`` is False (a
    scenario's VV then ends ``failed`` with the line and column when it is loaded).
    """
    if refuse_syntax_errors:
        problem = check_syntax(program)
        if problem is not None:
            raise ProgramRejected(problem)
    now = vvm.clock.now_s()
    vv = VirtualVehicle.objects.create(
        id=vv_id or uuid.uuid4(),
        customer=customer,
        name=name,
        program=program,
        seed=secrets.randbits(31) if seed is None else seed,
        start_ms=vvm.clock.epoch_ms(now),
        catalog=customer_catalog(customer=customer),
        submitted_s=now,
    )
    logger.info("vv submitted", extra={"vv": str(vv.id), "customer": customer.slug})
    if admit:
        vv_admit_queued(customer_id=customer.pk, vvm=vvm)
    vv.refresh_from_db()
    return vv


def _ground_station_for(vv: VirtualVehicle, near: Position | None = None) -> GroundStation | None:
    stations = list(
        GroundStation.objects.annotate(load=Count("vvs", filter=Q(vvs__status__in=ACTIVE_STATUSES)))
    )
    if not stations:
        return None
    if near is not None:
        return min(stations, key=lambda gs: (distance_m(near, gs.position), gs.name))
    return min(stations, key=lambda gs: (gs.load, gs.name))


def vv_admit_queued(*, customer_id: int, vvm: VVM) -> list[VirtualVehicle]:
    """Start the customer's oldest queued VVs while it runs fewer than its quota allows."""
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=customer_id)
        running = VirtualVehicle.objects.filter(customer=customer, status__in=ACTIVE_STATUSES)
        free = customer.max_parallel_vvs - running.count()
        if free <= 0:
            return []
        queued = VirtualVehicle.objects.filter(customer=customer, status=VVStatus.QUEUED)
        admitted = []
        for vv in queued.order_by("submitted_s", "created", "id")[:free]:
            gs = _ground_station_for(vv)
            if gs is None:
                logger.warning("no ground station: VV stays queued", extra={"vv": str(vv.id)})
                break
            vv.status = VVStatus.RUNNING
            vv.host_gs = gs
            vv.started_s = vvm.clock.now_s()
            vv.save(update_fields=["status", "host_gs", "started_s", "updated"])
            admitted.append(vv)
            vvm.dispatcher.vv_arrived(vv.id)
        return admitted


# --- steps -----------------------------------------------------------------------------------


def _pending_json(p: PendingRequest) -> dict[str, Any]:
    return {
        "kind": p.kind,
        "q": p.q,
        "r": p.fingerprint,
        "tasks": [
            {
                "position": {"lat": t.lat, "lng": t.lng, "alt": t.alt},
                "tolerance": t.tolerance_m,
                "sensors": list(t.sensors),
            }
            for t in p.tasks
        ],
        "open": list(p.open),
    }


def _pending_of(vv: VirtualVehicle) -> PendingRequest | None:
    data = vv.pending
    if not data:
        return None
    return PendingRequest(
        kind=data["kind"],
        q=int(data["q"]),
        fingerprint=data.get("r"),
        tasks=tuple(TaskRequest.from_json(t) for t in data["tasks"]),
        open=tuple(data.get("open", ())),
    )


class JournalView(Sequence[str]):
    """A VV's journal as the runtime reads it, each entry as the JSON text the database holds:
    a warm context asks only for the entries it does not have (and the last one it has, to
    check it is the same), a new one for all."""

    def __init__(self, vv: VirtualVehicle) -> None:
        self.vv = vv

    def __len__(self) -> int:
        return self.vv.journal_length

    def _texts(self) -> QuerySet[JournalEntry, str]:
        return (
            JournalEntry.objects.filter(vv_id=self.vv.pk)
            .annotate(text=Cast("entry", output_field=TextField()))
            .values_list("text", flat=True)
        )

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> list[str]: ...

    def __getitem__(self, index: int | slice) -> str | list[str]:
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            assert step == 1
            return list(self._texts().filter(seq__gte=start, seq__lt=stop).order_by("seq"))
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(index)
        return self._texts().get(seq=index)


def _journal_append(vv: VirtualVehicle, entry: dict[str, Any], vvm: VVM) -> None:
    """Add an answer to the VV's journal (the caller saves the VV in the same transaction)."""
    JournalEntry.objects.create(vv=vv, seq=vv.journal_length, entry=entry)
    vv.journal_length += 1
    vv.journal_bytes += len(json.dumps(entry, separators=(",", ":")))
    if vv.journal_length == settings.CPCC_JOURNAL_WARN_ENTRIES:
        LogEntry.objects.create(
            vv=vv,
            at_s=vvm.clock.now_s(),
            level="warning",
            message=f"the journal holds {vv.journal_length:,} answers; a VV stops at "
            f"{settings.CPCC_JOURNAL_MAX_ENTRIES:,} answers or "
            f"{settings.CPCC_JOURNAL_MAX_BYTES // 1_000_000} MB (every step replays it)",
        )


def _journal_full(vv: VirtualVehicle) -> str | None:
    if vv.journal_length > settings.CPCC_JOURNAL_MAX_ENTRIES:
        return (
            f"the journal holds {vv.journal_length:,} answers, more than the "
            f"{settings.CPCC_JOURNAL_MAX_ENTRIES:,} allowed (quota: journal)"
        )
    if vv.journal_bytes > settings.CPCC_JOURNAL_MAX_BYTES:
        return (
            f"the journal holds {vv.journal_bytes:,} bytes, more than the "
            f"{settings.CPCC_JOURNAL_MAX_BYTES:,} allowed (quota: journal)"
        )
    return None


def _step(vv: VirtualVehicle, vvm: VVM) -> StepResult:
    full = _journal_full(vv)
    if full is not None:
        return StepResult(Outcome.KILLED, error=VVError(ErrorKind.QUOTA, full, quota="journal"))
    step = StepInput(
        vv_id=str(vv.id),
        vv_name=vv.name,
        source=vv.program,
        seed=vv.seed,
        start_ms=vv.start_ms,
        catalog=vv.catalog,
        journal=JournalView(vv),
        effects_applied=vv.effects_applied,
        limits=customer_limits(customer=vv.customer),
        previous_step_s=vv.last_step_s,
    )
    result = vvm.runtime.step(step)
    _apply_effects(vv, result, vvm)
    vv.steps += 1
    vv.last_step_s = result.duration_s
    if result.outcome is Outcome.SUSPENDED and result.pending is not None:
        vv.pending = _pending_json(result.pending)
        _create_tasks(vv, result.pending, vvm)
    return result


def _apply_effects(vv: VirtualVehicle, result: StepResult, vvm: VVM) -> None:
    """Apply a step's storage writes and log lines: one upsert, one delete, one insert."""
    if result.effects:
        final: dict[str, tuple[str | None, float]] = {}  # key -> (value JSON or None, time)
        lines = []
        for effect in result.effects:
            at_s = vvm.clock.from_epoch_ms(effect.time_ms)
            if effect.op == "store" and effect.key is not None:
                final[effect.key] = (effect.value_json, at_s)
            elif effect.op == "remove" and effect.key is not None:
                final[effect.key] = (None, at_s)
            elif effect.op == "log" and effect.message is not None:
                lines.append(LogEntry(vv=vv, seq=effect.seq, at_s=at_s, message=effect.message))
        stored = [
            StorageDocument(
                vv=vv,
                key=key,
                value=json.loads(text),
                size_bytes=len(key) + len(text),
                updated_s=at_s,
            )
            for key, (text, at_s) in final.items()
            if text is not None
        ]
        if stored:
            StorageDocument.objects.bulk_create(
                stored,
                update_conflicts=True,
                unique_fields=["vv", "key"],
                update_fields=["value", "size_bytes", "updated_s"],
            )
        removed = [key for key, (text, _) in final.items() if text is None]
        if removed:
            StorageDocument.objects.filter(vv=vv, key__in=removed).delete()
        if lines:
            # A line is numbered by the program: applying it twice would be a duplicate.
            LogEntry.objects.bulk_create(lines, ignore_conflicts=True)
    vv.effects_applied = max(vv.effects_applied, result.effects_total)
    vv.storage_bytes = result.storage_bytes


def _create_tasks(vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> None:
    # A batch's tasks exist from its first suspension on; a single task is new each time.
    existing = (
        set(vv.tasks.filter(q=pending.q).values_list("index", flat=True))
        if pending.kind == "batch"
        else set()
    )
    now = vvm.clock.now_s()
    Task.objects.bulk_create(
        Task(
            vv=vv,
            q=pending.q,
            index=i,
            lat=t.lat,
            lng=t.lng,
            alt=t.alt,
            tolerance_m=t.tolerance_m,
            sensors=list(t.sensors),
            requested_s=now,
        )
        for i, t in enumerate(pending.tasks)
        if i in pending.open and i not in existing
    )


def vv_advance(*, vv_id: uuid.UUID, vvm: VVM) -> None:
    """What the host holding a VV does with it: step it, then route its pending task.

    Safe to call twice: a VV that waits for an RV, has ended or is queued is left alone.
    """
    with transaction.atomic():
        vv = (
            VirtualVehicle.objects.select_for_update(of=("self",))
            .select_related("customer", "host_gs", "host_rv")
            .get(pk=vv_id)
        )
        if vv.is_ended or vv.status == VVStatus.QUEUED:
            return
        if vv.status == VVStatus.MIGRATING:
            vv.status = VVStatus.RUNNING
        for _ in range(MAX_STEPS_PER_ADVANCE):
            if vv.pending is None:
                result = _step(vv, vvm)
                if result.outcome is not Outcome.SUSPENDED:
                    _end(vv, result, vvm)
                    break
            if not _route(vv, vvm):
                break
        else:
            # A program that keeps asking for tasks nobody can serve: let the host's other
            # work go first, then carry on (the tasks-per-VV quota bounds it).
            vvm.dispatcher.vv_arrived(vv.pk)
        vv.save()


def _end(vv: VirtualVehicle, result: StepResult, vvm: VVM) -> None:
    now = vvm.clock.now_s()
    if vv.host_rv is not None:
        gs = _ground_station_for(vv, near=vv.host_rv.position)
        reason = "finished" if result.outcome is Outcome.FINISHED else str(result.outcome)
        if gs is not None:
            _record_migration(vv, to=gs, reason=reason, vvm=vvm)
    vv.status = {
        Outcome.FINISHED: VVStatus.FINISHED,
        Outcome.FAILED: VVStatus.FAILED,
        Outcome.KILLED: VVStatus.KILLED,
    }[result.outcome]
    vv.pending = None
    if result.error is not None:
        vv.error = str(result.error)
        vv.error_line = result.error.line
        vv.error_column = result.error.column
    vv.finished_s = now
    vv.finished = dt.datetime.fromtimestamp(vvm.clock.epoch_ms(now) / 1000, tz=dt.UTC)
    _release_tasks(vv, vvm)
    vv.tasks.filter(status=TaskStatus.OPEN).update(status=TaskStatus.CANCELLED)
    logger.info(
        "vv ended",
        extra={"vv": str(vv.id), "customer": vv.customer.slug, "status": vv.status},
    )
    vvm.dispatcher.customer_slot_freed(vv.customer_id)


# --- routing and migration (the vehicle mapper and the migrator) -----------------------------


def vehicle_caps(vehicle: Vehicle, open_tasks: int = 0) -> VehicleCaps:
    """The mapper's view of one RV."""
    return VehicleCaps(
        id=vehicle.pk,
        name=vehicle.name,
        area=_polygon(json.dumps(vehicle.area)),
        min_altitude_m=vehicle.min_altitude_m,
        max_altitude_m=vehicle.max_altitude_m,
        sensors=_sensor_names(vehicle),
        active=vehicle.status == VehicleStatus.ACTIVE,
        position=vehicle.position,
        max_speed_mps=vehicle.max_speed_mps,
        open_tasks=open_tasks,
    )


# An RV's sensors, remembered per version of the vehicle row: a step on an RV asks each time
# whether the RV aboard can serve the next task. Changing the sensors touches the row
# (fleet.signals), so a new version is read again.
_sensors_seen: dict[tuple[int, Any], frozenset[str]] = {}


def _sensor_names(vehicle: Vehicle) -> frozenset[str]:
    if "sensors" in getattr(vehicle, "_prefetched_objects_cache", {}):
        return frozenset(s.name for s in vehicle.sensors.all())
    key = (vehicle.pk, vehicle.updated)
    names = _sensors_seen.get(key)
    if names is None:
        if len(_sensors_seen) > 10_000:
            _sensors_seen.clear()
        names = _sensors_seen[key] = frozenset(vehicle.sensors.values_list("name", flat=True))
    return names


@lru_cache(maxsize=1024)
def _polygon(area_json: str) -> Polygon:
    return Polygon([(float(lng), float(lat)) for lat, lng in json.loads(area_json)])


def fleet_caps(vvm: VVM) -> list[VehicleCaps]:
    """The mapper's view of the fleet: every RV that is in service or in maintenance; one whose
    worker is gone counts as in maintenance (it may come back)."""
    vehicles = (
        Vehicle.objects.exclude(status=VehicleStatus.REMOVED)
        .prefetch_related("sensors")
        .annotate(open_count=Count("tasks", filter=Q(tasks__status=TaskStatus.OPEN)))
    )
    caps = [vehicle_caps(v, v.open_count) for v in vehicles]
    if vvm.lease_s is not None:
        online = set(_online_vehicles(vvm).values_list("pk", flat=True))
        caps = [dataclasses.replace(c, active=c.active and c.id in online) for c in caps]
    return caps


def _online_vehicles(vvm: VVM) -> QuerySet[Vehicle]:
    assert vvm.lease_s is not None
    since = _as_datetime(vvm, vvm.clock.now_s() - vvm.lease_s)
    return Vehicle.objects.filter(worker_seen__gte=since)


def _as_datetime(vvm: VVM, t_s: float) -> dt.datetime:
    return dt.datetime.fromtimestamp(vvm.clock.epoch_ms(t_s) / 1000, tz=dt.UTC)


def _route(vv: VirtualVehicle, vvm: VVM) -> bool:
    """Find who serves the pending request. True when the VV must step again right here."""
    pending = _pending_of(vv)
    assert pending is not None
    open_tasks = list(vv.tasks.filter(q=pending.q, status=TaskStatus.OPEN).order_by("index"))
    host = vv.host_rv
    if host is not None and host.status == VehicleStatus.ACTIVE:
        # The common case needs no look at the rest of the fleet: the RV aboard can go on.
        caps = vehicle_caps(host)
        mine = [t for t in open_tasks if caps.can_serve(_request(t))]
        if mine:
            _assign(mine, host, vvm)
            return False
        if any(t.vehicle_id == host.pk for t in open_tasks):
            return False
    fleet = fleet_caps(vvm)
    decisions = {t.pk: map_task(_request(t), fleet) for t in open_tasks}
    rejected = [(t, decisions[t.pk]) for t in open_tasks if decisions[t.pk].rejected]
    # A batch is accepted or rejected as a whole, before any of its tasks is answered.
    partly_answered = JournalEntry.objects.filter(
        vv=vv, seq=vv.journal_length - 1, entry__q=pending.q
    ).exists()
    if rejected and not partly_answered:
        if vv.host_rv is not None:
            _migrate_to_ground_station(vv, reason="no vehicle can serve its task", vvm=vvm)
            return False
        _reject(vv, pending, rejected, vvm)
        return True

    best = _best_vehicle(open_tasks, decisions)
    if best is not None:
        vehicle = Vehicle.objects.get(pk=best.id)
        _release_tasks(vv, vvm)
        _record_migration(vv, to=vehicle, reason="its next task", vvm=vvm)
        vv.status = VVStatus.MIGRATING
        vvm.dispatcher.vv_arrived(vv.id)
        return False
    # Only RVs in maintenance could serve it: park on a ground station until one returns.
    if vv.host_rv is not None:
        _migrate_to_ground_station(vv, reason="waiting for a vehicle", vvm=vvm)
    return False


def _request(task: Task) -> TaskRequest:
    return TaskRequest(task.lat, task.lng, task.alt, task.tolerance_m, tuple(task.sensors))


def _best_vehicle(tasks: Sequence[Task], decisions: dict[int, MapDecision]) -> VehicleCaps | None:
    """The active RV serving most of the tasks; among equals the best ranked for the first."""
    score: dict[int, int] = {}
    rank: dict[int, tuple[int, int]] = {}
    by_id: dict[int, VehicleCaps] = {}
    for order, task in enumerate(tasks):
        for position, caps in enumerate(decisions[task.pk].candidates):
            score[caps.id] = score.get(caps.id, 0) + 1
            rank.setdefault(caps.id, (order, position))
            by_id[caps.id] = caps
    if not score:
        return None
    best = min(score, key=lambda vid: (-score[vid], rank[vid], by_id[vid].name))
    return by_id[best]


def _assign(tasks: Iterable[Task], vehicle: Vehicle, vvm: VVM) -> None:
    ids = [t.pk for t in tasks if t.vehicle_id != vehicle.pk]
    if ids:
        Task.objects.filter(pk__in=ids).update(vehicle=vehicle, assigned_s=vvm.clock.now_s())
        vvm.dispatcher.vehicle_changed(vehicle.pk)


def _release_tasks(vv: VirtualVehicle, vvm: VVM) -> None:
    """Take the VV's open tasks off the RVs they were planned on."""
    held = vv.tasks.filter(status=TaskStatus.OPEN, vehicle__isnull=False)
    vehicles = set(held.values_list("vehicle_id", flat=True))
    held.update(vehicle=None)
    for vehicle_id in sorted(vehicles):
        vvm.dispatcher.vehicle_changed(vehicle_id)


def _reject(
    vv: VirtualVehicle, pending: PendingRequest, rejected: list[tuple[Task, MapDecision]], vvm: VVM
) -> None:
    now = vvm.clock.now_s()
    task, decision = rejected[0]
    message = decision.reason or "no vehicle can serve the task"
    if pending.kind == "batch":
        message = f"task {task.index} of the batch: {message}"
    _journal_append(
        vv, answer_reject(pending, time_ms=vvm.clock.epoch_ms(now), message=message), vvm
    )
    vv.tasks.filter(q=pending.q, status=TaskStatus.OPEN).update(
        status=TaskStatus.REJECTED, message=message, done_s=now
    )
    vv.pending = None
    logger.info("task rejected", extra={"vv": str(vv.id), "reason": message})


def _record_migration(
    vv: VirtualVehicle, *, to: GroundStation | Vehicle, reason: str, vvm: VVM
) -> None:
    source: GroundStation | Vehicle | None = vv.host_rv or vv.host_gs
    to_kind = HostKind.RV if isinstance(to, Vehicle) else HostKind.GS
    if source is not None:
        Migration.objects.create(
            vv=vv,
            from_kind=HostKind.RV if isinstance(source, Vehicle) else HostKind.GS,
            from_name=source.name,
            to_kind=to_kind,
            to_name=to.name,
            at_s=vvm.clock.now_s(),
            reason=reason,
        )
    if isinstance(to, Vehicle):
        vv.host_rv, vv.host_gs = to, None
    else:
        vv.host_rv, vv.host_gs = None, to
    # The VV's warm context stays with the host it left: the new host resumes it by replay.
    vvm.runtime.forget(str(vv.pk))
    logger.info(
        "vv migrated",
        extra={"vv": str(vv.id), "from": getattr(source, "name", None), "to": to.name},
    )


def _migrate_to_ground_station(vv: VirtualVehicle, *, reason: str, vvm: VVM) -> None:
    near = vv.host_rv.position if vv.host_rv is not None else None
    gs = _ground_station_for(vv, near=near)
    if gs is None:
        return
    _release_tasks(vv, vvm)
    _record_migration(vv, to=gs, reason=reason, vvm=vvm)
    vv.status = VVStatus.MIGRATING
    vvm.dispatcher.vv_arrived(vv.id)


# --- task completion (the task executor's answer) -------------------------------------------


def task_complete(
    *,
    task_id: int,
    readings: list[dict[str, Any]],
    vvm: VVM,
    vehicle_id: int | None = None,
    vv_id: uuid.UUID | None = None,
) -> bool:
    """Record an RV's readings as the answer to a task and resume the VV on that RV.

    Returns False (and changes nothing) when the task is no longer open or no longer this
    vehicle's (``vehicle_id``): a duplicate delivery, or a VV that was cancelled or moved on
    meanwhile, e.g. because this RV's worker was taken for gone. A reading is never taken
    twice.
    """
    with transaction.atomic():
        # Lock the VV before its task, in the same order as vv_advance, so two workers
        # cannot deadlock.
        if vv_id is None:
            vv_id = Task.objects.values_list("vv_id", flat=True).get(pk=task_id)
        vv = VirtualVehicle.objects.select_for_update().get(pk=vv_id)
        task = Task.objects.select_for_update().get(pk=task_id)
        pending = _pending_of(vv)
        if task.status != TaskStatus.OPEN or pending is None or pending.q != task.q:
            return False
        if vehicle_id is not None and (
            task.vehicle_id != vehicle_id or vv.host_rv_id != vehicle_id
        ):
            return False
        now = vvm.clock.now_s()
        time_ms = vvm.clock.epoch_ms(now)
        if pending.kind == "batch":
            entry = answer_part(pending, index=task.index, time_ms=time_ms, data=readings)
        else:
            entry = answer_task(pending, time_ms=time_ms, data=readings)
        task.status = TaskStatus.DONE
        task.done_s = now
        task.readings = readings
        task.save(update_fields=["status", "done_s", "readings"])
        if task.vehicle_id is not None:
            Vehicle.objects.filter(pk=task.vehicle_id).update(tasks_done=F("tasks_done") + 1)
        _journal_append(vv, entry, vvm)
        vv.pending = None
        vv.save(update_fields=["journal_length", "journal_bytes", "pending", "updated"])
    vv_advance(vv_id=vv.pk, vvm=vvm)
    return True


# --- fleet changes -----------------------------------------------------------------------------


def vehicle_set_status(*, vehicle: Vehicle, status: VehicleStatus, vvm: VVM) -> None:
    """Put an RV into service, into maintenance, or remove it, without disturbing customers.

    The VVs aboard an RV that leaves service move to RVs that can serve their tasks, or wait
    on a ground station until one can; VVs waiting on a ground station are looked at again
    whenever an RV comes into service.
    """
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == status:
            return
        vehicle.status = status
        vehicle.save(update_fields=["status", "updated"])
        if status != VehicleStatus.ACTIVE:
            aboard = list(
                vehicle.vvs.exclude(status__in=ENDED_STATUSES).values_list("pk", flat=True)
            )
            Task.objects.filter(vehicle=vehicle, status=TaskStatus.OPEN).update(vehicle=None)
            for vv_id in aboard:
                vvm.dispatcher.vv_arrived(vv_id)
        logger.info("vehicle status", extra={"vehicle": vehicle.name, "status": status})
        vvm.dispatcher.vehicle_changed(vehicle.pk)
    if status == VehicleStatus.ACTIVE:
        vehicle_register(vehicle=vehicle, vvm=vvm)


def vvs_reroute_waiting(*, vvm: VVM) -> None:
    """Look again at every VV waiting on a ground station for an RV (after a fleet change)."""
    waiting = VirtualVehicle.objects.filter(
        status=VVStatus.RUNNING, host_gs__isnull=False, pending__isnull=False
    ).order_by("submitted_s", "id")
    for vv_id in waiting.values_list("pk", flat=True):
        vvm.dispatcher.vv_arrived(vv_id)


def vv_cancel(*, vv_id: uuid.UUID, vvm: VVM) -> bool:
    """Stop a VV at the customer's request: its open tasks are dropped, what it stored stays.

    Returns False when the VV had already ended. A VV aboard an RV goes back to a ground
    station, like any VV that ends.
    """
    with transaction.atomic():
        vv = (
            VirtualVehicle.objects.select_for_update(of=("self",))
            .select_related("customer", "host_gs", "host_rv")
            .get(pk=vv_id)
        )
        if vv.is_ended:
            return False
        now = vvm.clock.now_s()
        _release_tasks(vv, vvm)
        vv.tasks.filter(status=TaskStatus.OPEN).update(status=TaskStatus.CANCELLED)
        if vv.host_rv is not None:
            gs = _ground_station_for(vv, near=vv.host_rv.position)
            if gs is not None:
                _record_migration(vv, to=gs, reason="cancelled", vvm=vvm)
        was_queued = vv.status == VVStatus.QUEUED
        vv.status = VVStatus.CANCELLED
        vv.pending = None
        vv.error = "cancelled by its owner"
        vv.finished_s = now
        vv.finished = dt.datetime.fromtimestamp(vvm.clock.epoch_ms(now) / 1000, tz=dt.UTC)
        vv.save()
        vvm.runtime.forget(str(vv.pk))
        if not was_queued:
            vvm.dispatcher.customer_slot_freed(vv.customer_id)
    logger.info("vv cancelled", extra={"vv": str(vv_id)})
    return True


def vehicle_register(*, vehicle: Vehicle, vvm: VVM) -> None:
    """An RV came into service (new, or back from maintenance): it takes work at once.

    VVs waiting on a ground station for an RV are routed again, and a VV whose open tasks all
    lie in this RV's reach moves to it when it would get there sooner than the RV it is on
    (the mapper's estimate: flight time plus the queue of tasks). The caller has saved the
    vehicle and its sensors.
    """
    vvs_reroute_waiting(vvm=vvm)
    with transaction.atomic():
        vehicle = Vehicle.objects.prefetch_related("sensors").get(pk=vehicle.pk)
        if vehicle.status != VehicleStatus.ACTIVE:
            return
        newcomer = vehicle_caps(vehicle)
        fleet = {c.id: c for c in fleet_caps(vvm)}
        aboard_others = (
            VirtualVehicle.objects.select_for_update(of=("self",))
            .filter(status=VVStatus.RUNNING, host_rv__isnull=False, pending__isnull=False)
            .exclude(host_rv=vehicle)
            .select_related("customer", "host_rv")
            .order_by("submitted_s", "id")
        )
        for vv in aboard_others:
            tasks = list(vv.tasks.filter(status=TaskStatus.OPEN))
            host = fleet.get(vv.host_rv_id)  # type: ignore[arg-type]
            requests = [_request(t) for t in tasks]
            if not requests or host is None or not all(newcomer.can_serve(r) for r in requests):
                continue
            if newcomer.cost_s(requests[0]) >= host.cost_s(requests[0]):
                continue
            _release_tasks(vv, vvm)
            _record_migration(vv, to=vehicle, reason="a closer vehicle came into service", vvm=vvm)
            vv.status = VVStatus.MIGRATING
            vv.save(update_fields=["host_rv", "host_gs", "status", "updated"])
            vvm.dispatcher.vv_arrived(vv.pk)
            newcomer = vehicle_caps(vehicle, newcomer.open_tasks + len(tasks))
    vvm.dispatcher.vehicle_changed(vehicle.pk)


def vehicle_heartbeat(*, vehicle_id: int, vvm: VVM) -> None:
    """The vehicle's worker is alive (it renews its lease)."""
    Vehicle.objects.filter(pk=vehicle_id).update(worker_seen=_as_datetime(vvm, vvm.clock.now_s()))


def vehicles_check_leases(*, vvm: VVM) -> list[str]:
    """Move the VVs off every RV whose worker has stopped reporting; returns those RVs' names.

    The VVs wait on a ground station, which routes them to an RV that can serve them (this
    one again, if its worker comes back). Whatever that worker might still report for their
    tasks is refused (``task_complete`` checks the vehicle), so no reading is taken twice.
    """
    assert vvm.lease_s is not None
    gone = []
    online = _online_vehicles(vvm).values("pk")
    stale = (
        Vehicle.objects.exclude(pk__in=online).filter(vvs__status__in=ACTIVE_STATUSES).distinct()
    )
    for vehicle in stale:
        with transaction.atomic():
            stranded = (
                VirtualVehicle.objects.select_for_update(of=("self",))
                .filter(host_rv=vehicle, status__in=ACTIVE_STATUSES)
                .select_related("customer", "host_gs", "host_rv")
            )
            for vv in stranded:
                _migrate_to_ground_station(
                    vv, reason="its vehicle's worker stopped reporting", vvm=vvm
                )
                vv.save()
        gone.append(vehicle.name)
        logger.warning("vehicle worker lost", extra={"vehicle": vehicle.name})
    return gone


def vehicle_reconfigured(*, vehicle: Vehicle, vvm: VVM) -> None:
    """An RV's reach changed (area, altitude range, sensors): the tasks planned on it are taken
    off it and the VVs aboard route them again; they stay if it can still serve them and move
    to an RV that can otherwise. An RV in service with a larger reach takes work at once."""
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == VehicleStatus.REMOVED:
            return
        Task.objects.filter(vehicle=vehicle, status=TaskStatus.OPEN).update(vehicle=None)
        aboard = vehicle.vvs.exclude(status__in=ENDED_STATUSES).values_list("pk", flat=True)
        for vv_id in aboard:
            vvm.dispatcher.vv_arrived(vv_id)
        vvm.dispatcher.vehicle_changed(vehicle.pk)
    if vehicle.status == VehicleStatus.ACTIVE:
        vehicle_register(vehicle=vehicle, vvm=vvm)
