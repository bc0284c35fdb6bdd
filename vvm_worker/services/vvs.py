"""A VV's life: submission and admission (the loader), steps, the end, task answers, cancelling;
and what a user does with their VVs (submit copies, edit while queued, restart, cancel)."""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import json
import secrets
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from django.core.exceptions import ValidationError
from django.db import DatabaseError, connection, transaction
from django.db.models import F, JSONField, QuerySet, Value
from django.db.models.functions import Coalesce
from django.utils import timezone

from accounts.models import Customer, NotifyEvent, User
from accounts.selectors import customer_catalog
from cpcc_site import database
from cpcc_site.prepared import (
    PreparedRead,
    deferred,
    insert_rows,
    pipelined_transaction,
    save_fields,
    send_later,
)
from fleet.models import GroundStation, Vehicle
from missions.events import task_event, vv_event
from missions.models import (
    ACTIVE_STATUSES,
    LogEntry,
    StorageDocument,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
    WaitReason,
    vv_name_problem,
)
from missions.selectors import customer_has_queued_vv, vv_get_for_user
from vvm_worker.control import VehicleState
from vvm_worker.dispatch import HostRef
from vvm_worker.runtime import (
    ErrorKind,
    Outcome,
    PendingRequest,
    StepInput,
    StepResult,
    SyntaxProblem,
    VVError,
    answer_part,
    answer_reject,
    answer_task,
    check_syntax,
)
from vvm_worker.runtime.types import Effect
from vvm_worker.runtime.v8 import V8Closed
from vvm_worker.services.base import (
    VVM,
    ProgramRejected,
    VVAlreadyEnded,
    ground_station_for,
    ground_stations_loaded,
    logger,
    pending_json,
    pending_of,
)
from vvm_worker.services.calls import vv_answer_call, vv_answer_receive
from vvm_worker.services.customers import customer_limits
from vvm_worker.services.fleet import vehicle_record_state
from vvm_worker.services.images import pictures_received
from vvm_worker.services.journal import JournalView, journal_append, journal_full
from vvm_worker.services.notifications import ended_event, vv_notify
from vvm_worker.services.routing import (
    rv_statuses_read_ahead,
    tasks_reject,
    vv_record_migration,
    vv_release_tasks,
    vv_route,
)
from vvm_worker.services.service_levels import class_held_nudge, class_level
from vvm_worker.services.values import Unstorable, check_text, json_value


class NotACustomer(PermissionError):
    """The user belongs to no customer, so it cannot own VVs."""


class VVNotEnded(RuntimeError):
    """The VV has not ended yet, so it cannot be restarted."""

    def __init__(self, vv: VirtualVehicle) -> None:
        super().__init__(f"{vv.name} has not ended ({vv.status})")
        self.vv = vv


class VVNotQueued(RuntimeError):
    """The VV has left the queue (it started or ended), so its program can no longer change."""

    def __init__(self, vv: VirtualVehicle) -> None:
        super().__init__(f"{vv.name} is no longer queued ({vv.status})")
        self.vv = vv


class VVQueueFull(RuntimeError):
    """The customer's queue holds as many VVs as its quota allows (``max_queued_vvs``), so no
    more can be submitted until some start or are cancelled."""

    def __init__(self, customer: Customer, *, queued: int, adding: int) -> None:
        more = "one more" if adding == 1 else f"{adding} more"
        super().__init__(
            f"{customer.name} has {queued} VV(s) waiting in the queue and may have at most "
            f"{customer.max_queued_vvs} (its quota max_queued_vvs), so {more} cannot be "
            "submitted now: wait until some of them start, or cancel some, then submit again."
        )
        self.customer = customer
        self.queued = queued
        self.adding = adding


# Steps one host runs for one VV before it lets other work go first (rejected tasks in a row).
MAX_STEPS_PER_ADVANCE = 50
# Copies of one program a user may submit at once (the web editor's "copies").
MAX_COPIES = 50
_KEY_CHARS = StorageDocument._meta.get_field("key").max_length or 0
_SHOWN_KEY_CHARS = 40  # of a key quoted in an error
_JSON_NULL = Value(None, JSONField())


class _NotAnswered(Exception):
    """A task's answer went to the database with the VV's lock, and the VV turned out not to
    wait for it: the transaction rolls back."""


class _StepBroke(Exception):
    """The platform could not run a VV's step or apply its result: a bug of the platform (not
    a database outage), which would happen again on every retry."""

    def __init__(self, cause: Exception) -> None:
        super().__init__(f"{type(cause).__name__}: {cause}")
        self.cause = cause


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
    scenario's VV then ends ``failed`` with the line and column when it is loaded),
    ValidationError (naming ``name``) for a name with a control or bidirectional formatting
    character, and VVQueueFull when the customer's queue is full (``max_queued_vvs``; every
    submission counts: the API's, the editor's, a restart, a scenario's).
    """
    _check_name(name)
    if refuse_syntax_errors:
        problem = check_syntax(program)
        if problem is not None:
            raise ProgramRejected(problem)
    now = vvm.clock.now_s()
    with transaction.atomic():
        _check_queue(customer, adding=1)
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
    vvm.announce(lambda: vv_event(vv))
    if admit:
        for admitted in _admit(customer.pk, vvm):  # (one is queued: this one)
            if admitted.pk == vv.pk:  # as admission changed it
                vv.status, vv.host_gs, vv.started_s = (
                    admitted.status,
                    admitted.host_gs,
                    admitted.started_s,
                )
                vv.updated = admitted.updated
    return vv


def vvs_queue(
    *, customer: Customer, named_programs: Sequence[tuple[str, str]], vvm: VVM
) -> list[VirtualVehicle]:
    """Queue new VVs of the customer (a name and a checked program each) in the caller's
    transaction, all at once: one check of the queue quota for all of them (VVQueueFull:
    none is queued), one read of the customer's catalog, one insert. The caller asks for
    their admission once it commits (``Dispatcher.customer_slot_freed``)."""
    for name, _ in named_programs:
        _check_name(name)
    _check_queue(customer, adding=len(named_programs))
    now = vvm.clock.now_s()
    catalog = customer_catalog(customer=customer)
    vvs = VirtualVehicle.objects.bulk_create(
        VirtualVehicle(
            id=uuid.uuid4(),
            customer=customer,
            name=name,
            program=program,
            seed=secrets.randbits(31),
            start_ms=vvm.clock.epoch_ms(now),
            catalog=catalog,
            submitted_s=now,
        )
        for name, program in named_programs
    )
    for vv in vvs:
        logger.info("vv submitted", extra={"vv": str(vv.id), "customer": customer.slug})
    vvm.announce(lambda: [vv_event(vv) for vv in vvs])
    return vvs


def _check_name(name: str) -> None:
    problem = vv_name_problem(name)
    if problem is not None:
        raise ValidationError({"name": [problem]})


def _check_queue(customer: Customer, *, adding: int) -> None:
    """Raise VVQueueFull unless ``adding`` more queued VVs fit the customer's quota. Holds the
    customer's row until the transaction ends, as admission does, so that two submissions at
    once cannot both take the last place."""
    locked = Customer.objects.select_for_update().get(pk=customer.pk)
    queued = VirtualVehicle.objects.filter(customer=locked, status=VVStatus.QUEUED).count()
    if queued + adding > locked.max_queued_vvs:
        raise VVQueueFull(locked, queued=queued, adding=adding)


def vv_admit_queued(*, customer_id: int, vvm: VVM) -> list[VirtualVehicle]:
    """Start the customer's oldest queued VVs while it runs fewer than its quota allows,
    unless the fleet misses its service class's target now: then none starts and each says
    why it is held (``WaitReason.SERVICE_LEVEL``) until a later pass finds the class within
    its target (one of its tasks ends: ``class_held_nudge``; a ground station's sweep)."""
    if not customer_has_queued_vv(customer_id=customer_id):
        return []  # nothing waits (a VV that is queued later asks again)
    return _admit(customer_id, vvm)


def _admit(customer_id: int, vvm: VVM) -> list[VirtualVehicle]:
    with transaction.atomic():
        customer = Customer.objects.select_for_update().filter(pk=customer_id).first()
        if customer is None:  # a late message about a customer that was deleted
            return []
        running = VirtualVehicle.objects.filter(customer=customer, status__in=ACTIVE_STATUSES)
        free = customer.max_parallel_vvs - running.count()
        if free <= 0:
            return []
        queued = VirtualVehicle.objects.filter(customer=customer, status=VVStatus.QUEUED)
        if _held_by_service_level(customer, queued, vvm):
            return []
        admitted = list(queued.order_by("submitted_s", "created", "id")[:free])
        if not admitted:
            return []
        # Each to the ground station holding the fewest VVs (counting those admitted before
        # it), as ground_station_for would say one after the other: one read for all.
        stations = ground_stations_loaded()
        if not stations:
            first = admitted[0]
            logger.warning("no ground station: VV stays queued", extra={"vv": str(first.id)})
            return []
        now, stamp = vvm.clock.now_s(), timezone.now()
        by_station: dict[GroundStation, list[uuid.UUID]] = {}
        for vv in admitted:
            gs = min(stations, key=lambda gs: (gs.load, gs.name))
            gs.load += 1
            vv.status, vv.host_gs, vv.started_s, vv.updated = VVStatus.RUNNING, gs, now, stamp
            by_station.setdefault(gs, []).append(vv.pk)
        for gs, ids in by_station.items():  # one UPDATE a station
            VirtualVehicle.objects.filter(pk__in=ids).update(
                status=VVStatus.RUNNING, host_gs=gs, started_s=now, updated=stamp
            )
        for vv in admitted:
            vvm.announce(lambda vv=vv: vv_event(vv))
            vvm.dispatcher.vv_arrived(vv.id, on=HostRef(gs_id=vv.host_gs_id))
        return admitted


def _held_by_service_level(customer: Customer, queued: QuerySet[VirtualVehicle], vvm: VVM) -> bool:
    """Whether admission holds the customer's ``queued`` VVs because the fleet misses its
    service class's target now: their rows say so in the customer's words (one UPDATE). Once
    it keeps the target again, those held before are plain queued VVs again. A customer
    without a class is never held (and costs no query)."""
    if customer.service_class_id is None:
        return False
    now = vvm.clock.now_s()
    level = class_level(service_class=customer.service_class, now_s=now)
    if not level.missing:
        queued.filter(waiting_reason=WaitReason.SERVICE_LEVEL).update(
            waiting_reason="", waiting_message="", waiting_since_s=None
        )
        return False
    held = queued.update(
        waiting_reason=WaitReason.SERVICE_LEVEL,
        waiting_message=level.hold_message(),
        waiting_since_s=Coalesce(F("waiting_since_s"), Value(now)),
    )
    logger.info(
        "vvs held: the fleet misses the service class's target",
        extra={
            "customer": customer.slug,
            "service_class": level.spec.name,
            "target_p95_s": level.spec.p95_s,
            "p95_s": level.p95_s,
            "held": held,
        },
    )
    return True


def _slot_freed(vv: VirtualVehicle, vvm: VVM) -> None:
    """A VV of the customer that ran ended: admit its queued ones, and (its open tasks end
    with it) look again at the VVs of its class held for the class's target."""
    vvm.dispatcher.customer_slot_freed(vv.customer_id)
    class_held_nudge(service_class_id=vv.customer.service_class_id, vvm=vvm, told=vv.customer_id)


def _step(vv: VirtualVehicle, vvm: VVM) -> StepResult:
    """Run the VV's next step and apply what it did. Raises _StepBroke when that fails for any
    other reason than a database outage or a process that stops (both leave the step to be
    done again)."""
    try:
        return _run_step(vv, vvm)
    except Exception as exc:
        if isinstance(exc, V8Closed) or database.is_outage(exc):
            raise
        raise _StepBroke(exc) from exc


def _run_step(vv: VirtualVehicle, vvm: VVM) -> StepResult:
    full = journal_full(vv)
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
        replay_s=vv.last_step_s,
        cpu_spent_s=vv.call_cpu_s,
        picture_bytes=vv.picture_bytes,
    )
    result = vvm.runtime.step(step)
    # Its CPU since it last waited for the outside world (see ``VirtualVehicle.call_cpu_s``):
    # a replay's own share is the platform's, not the program's.
    vv.call_cpu_s += (
        max(0.0, result.duration_s - vv.last_step_s) if result.replayed else result.duration_s
    )
    refused = _apply_effects(vv, result, vvm)
    if refused is not None:
        logger.warning("vv step refused: %s", refused, extra=_about(vv))
        # The VV ends: its warm context (kept while it waited) holds effects never applied.
        vvm.runtime.forget(str(vv.id))
        result = StepResult(Outcome.FAILED, error=refused, duration_s=result.duration_s)
    vv.steps += 1
    vv.last_step_s = result.replay_time(vv.last_step_s)
    if result.outcome is Outcome.SUSPENDED and result.pending is not None:
        vv.pending = pending_json(result.pending)
    return result


def _apply_effects(vv: VirtualVehicle, result: StepResult, vvm: VVM) -> VVError | None:
    """Apply a step's storage writes and log lines: one upsert, one delete, one insert.

    When the database cannot store one of them (the runtime should have refused it already),
    nothing is applied and the VV's error is returned, saying which effect and why.
    """
    try:
        final, lines = _storable(vv, result.effects, vvm)
    except Unstorable as exc:
        message = f"the platform could not apply this step: {exc} (nothing of the step was applied)"
        return VVError(ErrorKind.PLATFORM, message)
    stored = [doc for doc in final.values() if doc is not None]
    removed = [key for key, doc in final.items() if doc is None]
    if removed:
        StorageDocument.objects.filter(vv=vv, key__in=removed).delete()
    # Checked above: the writes go without waiting (their answers are checked by the end of
    # the unit of work, see _unit_of_work).
    with deferred():
        if stored:
            insert_rows(
                stored,
                on_conflict="update",
                unique_fields=["vv", "key"],
                update_fields=["value", "size_bytes", "updated_s"],
            )
        if lines:
            # A line is numbered by the program: applying it twice would be a duplicate.
            insert_rows(lines, on_conflict="ignore")
    vv.effects_applied = max(vv.effects_applied, result.effects_total)
    vv.storage_bytes = result.storage_bytes
    return None


def _storable(
    vv: VirtualVehicle, effects: tuple[Effect, ...], vvm: VVM
) -> tuple[dict[str, StorageDocument | None], list[LogEntry]]:
    """A step's effects as rows: the last write of each key (None: removed) and the log lines.
    Raises Unstorable for the first effect that the database cannot store."""
    final: dict[str, StorageDocument | None] = {}
    lines = []
    for effect in effects:
        at_s = vvm.clock.from_epoch_ms(effect.time_ms)
        if effect.op in ("store", "remove") and effect.key is not None:
            key = effect.key
            where = f"storage key {_quoted(key)}"
            check_text(key, where=where)
            if len(key) > _KEY_CHARS:
                raise Unstorable(f"{where} is longer than {_KEY_CHARS} characters")
            text = effect.value_json if effect.op == "store" else None
            if text is None:
                final[key] = None
                continue
            value = json_value(text, where=f"the value stored under {where}")
            final[key] = StorageDocument(
                vv=vv,
                key=key,
                # JSON's null, not SQL's NULL (which the column refuses).
                value=_JSON_NULL if value is None else value,
                size_bytes=len(key.encode()) + len(text.encode()),  # in UTF-8, as stored
                updated_s=at_s,
            )
        elif effect.op == "log" and effect.message is not None:
            check_text(effect.message, where=f"log line {effect.seq}")
            lines.append(LogEntry(vv=vv, seq=effect.seq, at_s=at_s, message=effect.message))
    return final, lines


def _quoted(key: str) -> str:
    """A key as an error shows it: quoted, escaped to ASCII (it may hold what the database
    refuses, and the error is stored too), and cut if long."""
    shown = json.dumps(key[:_SHOWN_KEY_CHARS])
    return shown + ("..." if len(key) > _SHOWN_KEY_CHARS else "")


def _about(vv: VirtualVehicle) -> dict[str, str | None]:
    """What a log line about a VV names: the VV, its customer and the RV it is on."""
    rv = vv.host_rv
    return {"vv": str(vv.id), "customer": vv.customer.slug, "vehicle": rv and rv.name}


def _new_tasks(vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> list[Task] | None:
    """The tasks of a new request, not saved yet (routing decides their RV first, then
    ``_save_tasks`` saves them): a single task's; None for a batch, whose tasks exist from its
    first suspension on (they are saved here, and routing reads the open ones)."""
    now = vvm.clock.now_s()
    if pending.kind != "batch":
        (t,) = pending.tasks
        return [
            Task(
                vv=vv,
                q=pending.q,
                index=0,
                lat=t.lat,
                lng=t.lng,
                alt=t.alt,
                tolerance_m=t.tolerance_m,
                sensors=list(t.sensors),
                requested_s=now,
            )
        ]
    existing = set(vv.tasks.filter(q=pending.q).values_list("index", flat=True))
    new = [
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
    ]
    _save_tasks(vv, new, vvm)
    return None


def _save_tasks(vv: VirtualVehicle, tasks: list[Task] | None, vvm: VVM) -> None:
    """Save the new ones of these tasks (as routing left them: on an RV's list, or rejected)."""
    new = [t for t in tasks or () if t.pk is None]
    if new:
        with deferred():  # their keys are read by the end of the unit of work
            insert_rows(new)
        vvm.announce_at_commit(lambda: [task_event(task, vv.customer_id) for task in new])


def vv_advance(*, vv_id: uuid.UUID, vvm: VVM) -> None:
    """What the host holding a VV does with it: step it, then route its pending task.

    Safe to call twice: a VV that waits for an RV, has ended or is queued is left alone, and
    one that no longer exists (a late message) is ignored. A step the platform cannot run or
    apply (a bug of the platform, not of the program, or a statement the database refuses)
    is rolled back and the VV ends ``failed`` saying so; a database outage is raised, for the
    caller to wait out and redo.
    """
    try:
        _advance(vv_id, vvm)
    except _StepBroke as broke:
        # Retried, the step would break again and again: end the VV, in a new transaction
        # (the step's one is rolled back, so nothing of the step is half-applied).
        _end_broken(vv_id=vv_id, cause=broke.cause, vvm=vvm)


@contextlib.contextmanager
def _unit_of_work() -> Iterator[None]:
    """A VV's unit of work: one transaction, pipelined. A statement the database refuses
    (a platform bug: a step's writes are checked before they are sent; a deferred one is
    refused at the next statement that waits, or when the block ends) raises _StepBroke, as a
    step the platform cannot apply does; a database outage is raised as it is, for the
    caller to wait out and redo."""
    try:
        with pipelined_transaction():
            yield
    except DatabaseError as exc:
        if database.is_outage(exc):
            raise
        raise _StepBroke(exc) from exc


def _advance(vv_id: uuid.UUID, vvm: VVM) -> None:
    with _unit_of_work():
        vv = _locked_vv(vv_id)
        if vv is None or vv.is_ended or vv.status == VVStatus.QUEUED:
            return
        _advance_locked(vv, vvm)


# The columns of a VV row that advancing it may change: it writes those that did change.
_ADVANCED_FIELDS = (
    "status",
    "host_gs_id",
    "host_rv_id",
    "pending",
    "steps",
    "last_step_s",
    "effects_applied",
    "storage_bytes",
    "picture_bytes",
    "journal_length",
    "journal_bytes",
    "error",
    "error_line",
    "error_column",
    "finished_s",
    "finished",
    "call_cpu_s",
)


def _row(vv: VirtualVehicle) -> tuple[Any, ...]:
    return tuple(getattr(vv, name) for name in _ADVANCED_FIELDS)


def _save_changed(vv: VirtualVehicle, before: tuple[Any, ...]) -> None:
    """One UPDATE of the VV's row: the advanced columns that changed, and ``updated``."""
    changed = [
        name.removesuffix("_id")
        for name, old, new in zip(_ADVANCED_FIELDS, before, _row(vv), strict=True)
        if old != new
    ]
    with deferred():  # the unit holds the row: nothing to check, it may commit at once
        save_fields(vv, [*changed, "updated"], held=True)  # no VV signals: compiled once


def _advance_locked(vv: VirtualVehicle, vvm: VVM, *, before: tuple[Any, ...] | None = None) -> None:
    """Step the VV (held in this transaction) and route its pending request, as often as it
    needs, then write its row once. ``before``: the row as read, when the caller has changed
    the VV since (an answer)."""
    if before is None:
        before = _row(vv)
    if vv.status == VVStatus.MIGRATING:
        vv.status = VVStatus.RUNNING
    for _ in range(MAX_STEPS_PER_ADVANCE):
        tasks = None
        stepped = vv.pending is None
        if stepped:
            result = _step(vv, vvm)
            if result.outcome is not Outcome.SUSPENDED:
                _end(vv, result, vvm)
                break
        pending = result.pending if stepped else pending_of(vv)
        assert pending is not None
        if pending.kind == "call":  # answered here and now; the program goes on
            over = _host_call(vv, pending, vvm)
            if over is not None:
                _end(vv, over, vvm)
                break
            continue
        if pending.kind == "message":
            if _host_receive(vv, pending, vvm):
                continue
            break  # it waits for a message (or its timeout) on a ground station
        if stepped:
            tasks = _new_tasks(vv, pending, vvm)
        again = vv_route(vv=vv, vvm=vvm, open_tasks=tasks)
        _save_tasks(vv, tasks, vvm)
        if not again:
            break
    else:
        # A program that keeps asking for tasks nobody can serve, or makes call after call:
        # let the host's other work go first, then carry on (the tasks-per-VV quota and the
        # CPU quota bound it).
        vvm.dispatcher.vv_arrived(vv.pk, on=HostRef(rv_id=vv.host_rv_id, gs_id=vv.host_gs_id))
    _save_changed(vv, before)
    vvm.announce(lambda: vv_event(vv))


def _host_call(vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> StepResult | None:
    """``vv_answer_call``; a failure that is not the program's (a platform bug) breaks the
    step, as in ``_step``."""
    try:
        return vv_answer_call(
            vv=vv, pending=pending, limits=customer_limits(customer=vv.customer), vvm=vvm
        )
    except Exception as exc:
        if isinstance(exc, V8Closed) or database.is_outage(exc):
            raise
        raise _StepBroke(exc) from exc


def _host_receive(vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> bool:
    """``vv_answer_receive``; failures as in ``_host_call``."""
    try:
        return vv_answer_receive(vv=vv, pending=pending, vvm=vvm)
    except Exception as exc:
        if database.is_outage(exc):
            raise
        raise _StepBroke(exc) from exc


# Every service holds a VV's row FOR NO KEY UPDATE (no_key): it never changes the row's key,
# and the lock does not conflict with the key-share locks that rows referring to the VV take
# (an RV's track points for every VV aboard, written in an answer's transaction while another
# process holds some of those VVs).
_LOCKED_VV = PreparedRead(
    lambda vv_id: (
        VirtualVehicle.objects.select_for_update(of=("self",), no_key=True)
        .select_related("customer__service_class", "host_gs", "host_rv")
        .filter(pk=vv_id)
    ),
    samples=[("pk", uuid.UUID(int=0))],
)


def _locked_vv(vv_id: uuid.UUID) -> VirtualVehicle | None:
    """The VV's row with its customer and hosts, held until the transaction ends."""
    return _LOCKED_VV.first(vv_id)


def _end_broken(*, vv_id: uuid.UUID, cause: Exception, vvm: VVM) -> None:
    """End a VV ``failed`` whose step the platform could not run or apply. The error names
    the exception's type only; the traceback goes to the platform's log."""
    with transaction.atomic():
        vv = _locked_vv(vv_id)
        if vv is None or vv.is_ended:
            return
        logger.error("vv step broke: the VV fails", exc_info=cause, extra=_about(vv))
        vvm.runtime.forget(str(vv.id))  # the context may be in any state
        message = f"the platform could not run or apply this VV's step ({type(cause).__name__})"
        _end(vv, StepResult(Outcome.FAILED, error=VVError(ErrorKind.PLATFORM, message)), vvm)
        vv.save()
        vvm.announce(lambda: vv_event(vv))


def _end(vv: VirtualVehicle, result: StepResult, vvm: VVM) -> None:
    now = vvm.clock.now_s()
    vvm.settle_host(vv.host_rv)  # it leaves those aboard
    if vv.host_rv is not None:
        gs = ground_station_for(vv, near=vv.host_rv.position)
        reason = "finished" if result.outcome is Outcome.FINISHED else str(result.outcome)
        if gs is not None:
            vv_record_migration(vv=vv, to=gs, reason=reason, vvm=vvm)
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
    _cancel_open_tasks(vv, vvm)
    logger.info(
        "vv ended",
        extra={"vv": str(vv.id), "customer": vv.customer.slug, "status": vv.status},
    )
    _slot_freed(vv, vvm)
    event = ended_event(vv.status)
    if event is not None:
        vv_notify(vv=vv, event=event, vvm=vvm, at_ms=vvm.clock.epoch_ms(now))


# A VV's open tasks (SQL written once: read for every VV that ends).
_OPEN_TASKS = PreparedRead(
    lambda vv_id: Task.objects.filter(vv_id=vv_id, status=TaskStatus.OPEN),
    samples=[("vv_id", uuid.UUID(int=0))],
)


def _cancel_open_tasks(vv: VirtualVehicle, vvm: VVM) -> None:
    """Cancel the VV's open tasks and take them off the RVs they were planned on."""
    open_tasks = _OPEN_TASKS.all(vv.pk)
    if not open_tasks:
        return
    vv_release_tasks(vv=vv, vvm=vvm, open_tasks=open_tasks)
    vv.tasks.filter(pk__in=[t.pk for t in open_tasks]).update(status=TaskStatus.CANCELLED)
    for task in open_tasks:
        task.status = TaskStatus.CANCELLED
    vvm.announce(lambda: [task_event(task, vv.customer_id) for task in open_tasks])


# --- task completion (the task executor's answer) -------------------------------------------


def task_complete(
    *,
    task_id: int,
    readings: list[dict[str, Any]],
    vvm: VVM,
    vehicle_id: int | None = None,
    vv_id: uuid.UUID | None = None,
    arrival: VehicleState | None = None,
    failure: str | None = None,
    q: int | None = None,
) -> bool:
    """Record an RV's readings as the answer to a task and resume the VV on that RV: one unit
    of work (one transaction) with the VV's step and the routing of its next request, and
    with ``arrival``, the RV's report of where it stopped to serve it (``vehicle_id``'s state,
    on the track of the VVs aboard), which is recorded only if the answer is.

    ``failure``: the RV could not take the readings (a sensor that did not answer, said in
    words the customer may read): the task ends rejected with it, and so does the VV's
    request (a whole ``executeAll`` batch), which the program sees as a ``TaskRejectedError``.

    ``q``: the VV's request the task belongs to, when the caller knows it: the task's update
    then goes to the database with the VV's lock, in one round trip.

    Returns False (and changes nothing) when the task is no longer open or no longer this
    vehicle's (``vehicle_id``): a duplicate delivery, or a VV that was cancelled or moved on
    meanwhile, e.g. because this RV's worker was taken for gone. A reading is never taken
    twice. A step the platform cannot run or apply ends the VV ``failed`` (False: its task is
    cancelled with it).
    """
    if vv_id is None:
        vv_id = Task.objects.values_list("vv_id", flat=True).get(pk=task_id)
    try:
        # (The statuses of the RVs of this process go to the database with the VV's lock:
        # routing the VV's next request needs them.)
        with _unit_of_work(), rv_statuses_read_ahead(vvm=vvm):
            return _answer_and_advance(
                task_id, readings, vvm, vehicle_id, vv_id, arrival, failure=failure, q=q
            )
    except _NotAnswered:
        return False
    except _StepBroke as broke:
        # Retried, the step would break again and again. The transaction is rolled back, so
        # nothing of the step is half-applied: the answer is recorded again on its own, and
        # the VV ends, in a transaction of its own.
        with transaction.atomic():
            answered = _answer_and_advance(
                task_id, readings, vvm, vehicle_id, vv_id, arrival, advance=False, failure=failure
            )
        _end_broken(vv_id=vv_id, cause=broke.cause, vvm=vvm)
        return answered


def _answer_and_advance(
    task_id: int,
    readings: list[dict[str, Any]],
    vvm: VVM,
    vehicle_id: int | None,
    vv_id: uuid.UUID,
    arrival: VehicleState | None,
    *,
    advance: bool = True,
    failure: str | None = None,
    q: int | None = None,
) -> bool:
    # The VV first (held until the end of the transaction), then its task: the order every
    # service takes them in, so two workers cannot deadlock. When the caller knows the task's
    # request (``q``, the RV's loop does), both go to the database at once and their answers
    # come back together; should the VV then not be waiting for that answer here, the task's
    # update is rolled back with the transaction.
    now = vvm.clock.now_s()

    def answer(request: int) -> Callable[[], Task | None]:
        return _answer_task(
            task_id,
            vv_id,
            q=request,
            vehicle_id=vehicle_id,
            now=now,
            readings=[] if failure is not None else readings,
            status=TaskStatus.DONE if failure is None else TaskStatus.REJECTED,
        )

    read_vv = _LOCKED_VV.first_later(vv_id)
    read_task = None if q is None else answer(q)
    vv = read_vv()
    pending = None if vv is None else pending_of(vv)
    if (
        vv is None
        or vv.is_ended
        or vv.status == VVStatus.QUEUED
        or pending is None
        or (vehicle_id is not None and vv.host_rv_id != vehicle_id)
        or (q is not None and pending.q != q)
    ):
        if read_task is not None and read_task() is not None:
            raise _NotAnswered()  # (an answer to a request the VV no longer waits for)
        return False
    if read_task is None:
        read_task = answer(pending.q)
    task = read_task()
    if task is None:
        return False
    served_by = task.vehicle_id
    before = _row(vv)
    time_ms = vvm.clock.epoch_ms(now)
    if failure is not None:
        entry = _reading_failed(vv, task, pending, failure, now=now, vvm=vvm)
    elif pending.kind == "batch":
        entry = answer_part(pending, index=task.index, time_ms=time_ms, data=readings)
    else:
        entry = answer_task(pending, time_ms=time_ms, data=readings)
    if failure is None:
        pictures_received(vv=vv, readings=readings)
    vvm.announce(lambda: task_event(task, vv.customer_id))
    class_held_nudge(service_class_id=vv.customer.service_class_id, vvm=vvm)
    if failure is None:
        vv_notify(vv=vv, event=NotifyEvent.TASK_DONE, vvm=vvm, at_ms=time_ms, task_id=task_id)
    settled = (
        vvm.local_fleet.settle(vehicle_id, tasks_done=1)
        if vvm.local_fleet is not None and vehicle_id is not None
        else None
    )
    if settled is not None:  # its reports (its arrival here) and the task it served
        host = vv.host_rv
        if host is not None and settled.position is not None:
            here = settled.position
            host.lat, host.lng, host.alt = here.lat, here.lng, here.alt
    elif arrival is not None and vehicle_id is not None:
        vehicle_record_state(vehicle_id=vehicle_id, state=arrival, track_aboard=True, tasks_done=1)
        host = vv.host_rv
        if host is not None:  # as read before the report: where the VV leaves from
            here = arrival.position
            host.lat, host.lng, host.alt = here.lat, here.lng, here.alt
    elif served_by is not None:
        Vehicle.objects.filter(pk=served_by).update(tasks_done=F("tasks_done") + 1)
    journal_append(vv, entry, vvm)
    vv.pending = None
    if advance:
        _advance_locked(vv, vvm, before=before)
    else:
        _save_changed(vv, before)
    return True


def _reading_failed(
    vv: VirtualVehicle,
    task: Task,
    pending: PendingRequest,
    failure: str,
    *,
    now: float,
    vvm: VVM,
) -> dict[str, Any]:
    """The task (answered rejected by the caller) ends with the RV's failure to read its
    sensors, and the VV's request with it: the journal entry that rejects it. The other open
    tasks of a batch end rejected too, off the RVs they were planned on."""
    message = f"the vehicle took no reading: {failure}"
    if pending.kind == "batch":
        message = f"task {task.index} of the batch: {message}"
    task.message = message
    Task.objects.filter(pk=task.pk).update(message=message)
    others = list(vv.tasks.filter(q=pending.q, status=TaskStatus.OPEN))
    if others:
        vv_release_tasks(vv=vv, vvm=vvm, open_tasks=others)
        tasks_reject(vv=vv, tasks=others, message=message, now=now, vvm=vvm)
    logger.warning("reading failed", extra={**_about(vv), "reason": failure})
    return answer_reject(pending, time_ms=vvm.clock.epoch_ms(now), message=message)


def _answer_task(
    task_id: int,
    vv_id: uuid.UUID,
    *,
    q: int,
    vehicle_id: int | None,
    now: float,
    readings: list[dict[str, Any]],
    status: TaskStatus = TaskStatus.DONE,
) -> Callable[[], Task | None]:
    """Mark the task done with its readings, if it is still open, of the VV's request ``q``
    and (``vehicle_id``) on this RV's list: a fenced UPDATE, which gives back what the answer
    and the map need of the task (no read before or after it). Sent now; the function it
    gives back reads the answer: the task, or None if it was not so (in a ``pipelined`` unit
    of work, together with what was sent before it)."""
    meta = Task._meta
    fence = [
        task_id,
        meta.get_field("vv").get_db_prep_value(vv_id, connection),
        q,
        TaskStatus.OPEN.value,
        *(() if vehicle_id is None else (vehicle_id,)),
    ]
    row_later = send_later(
        _answer_sql(connection.vendor, on_vehicle=vehicle_id is not None),
        [
            status.value,
            now,
            meta.get_field("readings").get_db_prep_save(readings, connection),
            *fence,
        ],
    )

    def read() -> Task | None:
        row = row_later()
        if row is None:
            return None
        index, served_by, lat, lng, alt, requested_s = row
        return Task(
            id=task_id,
            vv_id=vv_id,
            q=q,
            index=index,
            lat=lat,
            lng=lng,
            alt=alt,
            status=status,
            vehicle_id=served_by,
            requested_s=requested_s,
            done_s=now,
            readings=readings,
        )

    return read


@functools.cache
def _answer_sql(vendor: str, *, on_vehicle: bool) -> str:
    """``_answer_task``'s statement, written once per database and fence."""
    meta, quote = Task._meta, connection.ops.quote_name

    def column(name: str) -> str:
        return quote(meta.get_field(name).column)

    fence = ["id", "vv", "q", "status", *(("vehicle",) if on_vehicle else ())]
    returned = ("index", "vehicle", "lat", "lng", "alt", "requested_s")
    return (
        f"UPDATE {quote(meta.db_table)} SET {column('status')} = %s, "
        f"{column('done_s')} = %s, {column('readings')} = %s "
        f"WHERE {' AND '.join(f'{column(name)} = %s' for name in fence)} "
        f"RETURNING {', '.join(column(name) for name in returned)}"
    )


def vv_cancel(*, vv_id: uuid.UUID, vvm: VVM) -> bool:
    """Stop a VV at the customer's request: its open tasks are dropped, what it stored stays.

    Returns False when the VV had already ended. A VV aboard an RV goes back to a ground
    station, like any VV that ends.
    """
    with transaction.atomic():
        vv = (
            VirtualVehicle.objects.select_for_update(of=("self",), no_key=True)
            .select_related("customer", "host_gs", "host_rv")
            .get(pk=vv_id)
        )
        if vv.is_ended:
            return False
        now = vvm.clock.now_s()
        vvm.settle_host(vv.host_rv)  # it leaves those aboard
        _cancel_open_tasks(vv, vvm)
        if vv.host_rv is not None:
            gs = ground_station_for(vv, near=vv.host_rv.position)
            if gs is not None:
                vv_record_migration(vv=vv, to=gs, reason="cancelled", vvm=vvm)
        was_queued = vv.status == VVStatus.QUEUED
        vv.status = VVStatus.CANCELLED
        vv.pending = None
        vv.error = "cancelled by its owner"
        vv.finished_s = now
        vv.finished = dt.datetime.fromtimestamp(vvm.clock.epoch_ms(now) / 1000, tz=dt.UTC)
        vv.save()
        vvm.announce(lambda: vv_event(vv))
        vvm.runtime.forget(str(vv.pk))
        if not was_queued:
            _slot_freed(vv, vvm)
    logger.info("vv cancelled", extra={"vv": str(vv_id)})
    return True


def copy_names(*, name: str, copies: int) -> list[str]:
    """The names of ``copies`` copies of a VV: ``name``, ``name (2)``, ``name (3)``, ..."""
    return [name if n == 1 else f"{name} ({n})" for n in range(1, copies + 1)]


def _submit_copies(
    *, customer: Customer, name: str, program: str, copies: int, vvm: VVM
) -> list[VirtualVehicle]:
    """Queue ``copies`` VVs of one program in one transaction and, once it commits, ask the
    ground-station workers to admit the customer's queued VVs. Raises ProgramRejected for a
    syntax error (checked once; nothing is created), ValidationError for a refused name and
    VVQueueFull when the copies do not all fit the customer's queue (nothing is created)."""
    if not 1 <= copies <= MAX_COPIES:
        raise ValueError(f"copies must be between 1 and {MAX_COPIES}, not {copies}")
    _check_name(name)
    problem = check_syntax(program)
    if problem is not None:
        raise ProgramRejected(problem)
    with transaction.atomic():
        vvs = vvs_queue(  # all of them or none
            customer=customer,
            named_programs=[(n, program) for n in copy_names(name=name, copies=copies)],
            vvm=vvm,
        )
        vvm.dispatcher.customer_slot_freed(customer.pk)
    return vvs


def vv_create_copies_for_user(
    *, user: User, name: str, program: str, copies: int, vvm: VVM
) -> tuple[list[VirtualVehicle], SyntaxProblem | None]:
    """Queue ``copies`` (1 to MAX_COPIES) new VVs of the user's customer running one program,
    named ``name``, ``name (2)``, ``name (3)``, ... (``copy_names``); a program with a syntax
    error is refused with where the error is, and nothing is created.

    Returns the VVs in that order, queued: once the transaction that created them all commits,
    the ground-station workers are asked to admit the customer's queued VVs within its quota
    of parallel VVs (the others wait in the queue). Raises NotACustomer for a user of no
    customer and ValueError for a number of copies out of range.
    """
    if user.customer is None:
        raise NotACustomer(f"{user.username} belongs to no customer")
    try:
        vvs = _submit_copies(
            customer=user.customer, name=name, program=program, copies=copies, vvm=vvm
        )
    except ProgramRejected as exc:
        return [], exc.problem
    return vvs, None


def vv_create_for_user(
    *, user: User, name: str, program: str, vvm: VVM
) -> tuple[VirtualVehicle | None, SyntaxProblem | None]:
    """Queue a new VV of the user's customer, from the web or the REST API; a program with a
    syntax error is refused with where the error is (and nothing is created).

    The VV is returned queued: once the transaction commits, the ground-station workers are
    asked to admit the customer's queued VVs within its quota of parallel VVs. Raises
    NotACustomer for a user of no customer.
    """
    vvs, problem = vv_create_copies_for_user(
        user=user, name=name, program=program, copies=1, vvm=vvm
    )
    return (vvs[0] if vvs else None), problem


def vv_restart_for_user(*, user: User, vv_id: uuid.UUID | str, vvm: VVM) -> VirtualVehicle:
    """Start an ended VV (finished, failed, killed or cancelled) again: a new VV of the same
    customer with the same name and program, queued and admitted like a new submission (a new
    seed, an empty storage and log). The ended VV stays as it is.

    Staff may restart any VV (the new one belongs to the VV's customer). Raises VVNotFound for
    a missing VV or another customer's, VVNotEnded while it is queued or running, and
    ProgramRejected when its program does not parse (a scenario's VV that failed so).
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if not vv.is_ended:
        raise VVNotEnded(vv)
    (new,) = _submit_copies(
        customer=vv.customer, name=vv.name, program=vv.program, copies=1, vvm=vvm
    )
    logger.info(
        "vv restarted", extra={"vv": str(new.pk), "from_vv": str(vv.pk), "user": user.username}
    )
    return new


def vv_update_program_for_user(
    *, user: User, vv_id: uuid.UUID | str, name: str, program: str, vvm: VVM
) -> VirtualVehicle:
    """Change the name and program of one of the user's VVs while it waits in the queue; it
    keeps its place there.

    Raises VVNotFound for a missing VV or another customer's, ValidationError (naming
    ``name``) for a name with a control or bidirectional formatting character,
    ProgramRejected (with the line and column) for a program with a syntax error, and
    VVNotQueued once the VV has started or ended. Returns the VV as it is afterwards.
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    _check_name(name)
    problem = check_syntax(program)
    if problem is not None:
        raise ProgramRejected(problem)
    with transaction.atomic():
        # Admission holds the customer's row while it starts queued VVs: taking it first (then
        # the VV's, in admission's order) means a VV starts either before the change, which is
        # then refused, or after it, with the new program.
        Customer.objects.select_for_update().filter(pk=vv.customer_id).first()
        locked = VirtualVehicle.objects.select_for_update(of=("self",), no_key=True).get(pk=vv.pk)
        if locked.status != VVStatus.QUEUED:
            raise VVNotQueued(locked)
        locked.name = name
        locked.program = program
        locked.save(update_fields=["name", "program", "updated"])
        vvm.announce(lambda: vv_event(locked))
    logger.info("vv program changed", extra={"vv": str(vv.pk), "user": user.username})
    return vv_get_for_user(user=user, vv_id=vv.pk)


def vv_cancel_for_user(*, user: User, vv_id: uuid.UUID | str, vvm: VVM) -> VirtualVehicle:
    """Cancel one of the user's VVs: its open tasks are dropped, what it stored stays.

    Raises VVNotFound for a missing VV or another customer's, and VVAlreadyEnded when it had
    already finished, failed, been killed or cancelled. Returns the VV as it is afterwards.
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if not vv_cancel(vv_id=vv.pk, vvm=vvm):
        vv.refresh_from_db()
        raise VVAlreadyEnded(vv)
    return vv_get_for_user(user=user, vv_id=vv.pk)
