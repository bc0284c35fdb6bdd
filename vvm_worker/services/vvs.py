"""A VV's life: submission and admission (the loader), steps, the end, task answers, cancelling;
and what a user does with their VVs (submit copies, edit while queued, restart, cancel)."""

from __future__ import annotations

import datetime as dt
import uuid
from collections.abc import Callable
from typing import Any

from django.db import transaction
from django.db.models import F

from accounts.models import NotifyEvent
from cpcc_site import database
from fleet.models import Vehicle
from missions.events import task_event, vv_event
from missions.models import (
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from vvm_worker.control import VehicleState
from vvm_worker.dispatch import HostRef
from vvm_worker.runtime import (
    ErrorKind,
    Outcome,
    PendingRequest,
    StepResult,
    VVError,
    answer_part,
    answer_reject,
    answer_task,
)
from vvm_worker.runtime.v8 import V8Closed
from vvm_worker.services.admission import slot_freed
from vvm_worker.services.base import (
    VVM,
    ground_station_for,
    logger,
    pending_of,
)
from vvm_worker.services.calls import vv_answer_call, vv_answer_receive
from vvm_worker.services.customers import customer_limits
from vvm_worker.services.fleet import vehicle_record_state
from vvm_worker.services.images import pictures_received
from vvm_worker.services.journal import journal_append
from vvm_worker.services.notifications import ended_event, vv_notify
from vvm_worker.services.routing import (
    rv_statuses_read_ahead,
    tasks_reject,
    vv_record_migration,
    vv_release_tasks,
    vv_route,
)
from vvm_worker.services.service_levels import class_held_nudge
from vvm_worker.services.steps import about, new_tasks_of, step_and_apply, tasks_save
from vvm_worker.services.store import (
    StepBroke,
    locked_vv,
    locked_vv_later,
    open_tasks_of,
    take_answer,
    unit_of_work,
    vv_row,
    vv_save_changes,
)


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


MAX_STEPS_PER_ADVANCE = 50


class _NotAnswered(Exception):
    """A task's answer went to the database with the VV's lock, and the VV turned out not to
    wait for it: the transaction rolls back."""


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
    except StepBroke as broke:
        # Retried, the step would break again and again: end the VV, in a new transaction
        # (the step's one is rolled back, so nothing of the step is half-applied).
        _end_broken(vv_id=vv_id, cause=broke.cause, vvm=vvm)


def _advance(vv_id: uuid.UUID, vvm: VVM) -> None:
    with unit_of_work():
        vv = locked_vv(vv_id)
        if vv is None or vv.is_ended or vv.status == VVStatus.QUEUED:
            return
        _advance_locked(vv, vvm)


def _advance_locked(vv: VirtualVehicle, vvm: VVM, *, before: tuple[Any, ...] | None = None) -> None:
    """Step the VV (held in this transaction) and route its pending request, as often as it
    needs, then write its row once. ``before``: the row as read, when the caller has changed
    the VV since (an answer)."""
    if before is None:
        before = vv_row(vv)
    if vv.status == VVStatus.MIGRATING:
        vv.status = VVStatus.RUNNING
    for _ in range(MAX_STEPS_PER_ADVANCE):
        tasks = None
        stepped = vv.pending is None
        if stepped:
            result = step_and_apply(vv=vv, vvm=vvm)
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
            tasks = new_tasks_of(vv=vv, pending=pending, vvm=vvm)
        again = vv_route(vv=vv, vvm=vvm, open_tasks=tasks)
        tasks_save(vv=vv, tasks=tasks, vvm=vvm)
        if not again:
            break
    else:
        # A program that keeps asking for tasks nobody can serve, or makes call after call:
        # let the host's other work go first, then carry on (the tasks-per-VV quota and the
        # CPU quota bound it).
        vvm.dispatcher.vv_arrived(vv.pk, on=HostRef(rv_id=vv.host_rv_id, gs_id=vv.host_gs_id))
    vv_save_changes(vv, before)
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
        raise StepBroke(exc) from exc


def _host_receive(vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> bool:
    """``vv_answer_receive``; failures as in ``_host_call``."""
    try:
        return vv_answer_receive(vv=vv, pending=pending, vvm=vvm)
    except Exception as exc:
        if database.is_outage(exc):
            raise
        raise StepBroke(exc) from exc


def _end_broken(*, vv_id: uuid.UUID, cause: Exception, vvm: VVM) -> None:
    """End a VV ``failed`` whose step the platform could not run or apply. The error names
    the exception's type only; the traceback goes to the platform's log."""
    with transaction.atomic():
        vv = locked_vv(vv_id)
        if vv is None or vv.is_ended:
            return
        logger.error("vv step broke: the VV fails", exc_info=cause, extra=about(vv))
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
    slot_freed(vv, vvm)
    event = ended_event(vv.status)
    if event is not None:
        vv_notify(vv=vv, event=event, vvm=vvm, at_ms=vvm.clock.epoch_ms(now))


def _cancel_open_tasks(vv: VirtualVehicle, vvm: VVM) -> None:
    """Cancel the VV's open tasks and take them off the RVs they were planned on."""
    open_tasks = open_tasks_of(vv.pk)
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
        with unit_of_work(), rv_statuses_read_ahead(vvm=vvm):
            return _answer_and_advance(
                task_id, readings, vvm, vehicle_id, vv_id, arrival, failure=failure, q=q
            )
    except _NotAnswered:
        return False
    except StepBroke as broke:
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
    """``task_complete``'s unit of work: the answer held, journaled and heard of, the serving
    RV counted, then the VV stepped on (``advance``) or only saved."""
    now = vvm.clock.now_s()
    held = _held_answer(
        task_id, vv_id, vehicle_id=vehicle_id, q=q, now=now, readings=readings, failure=failure
    )
    if held is None:
        return False
    vv, pending, task = held
    before = vv_row(vv)
    entry = _answer_entry(vv, task, pending, readings, failure=failure, now=now, vvm=vvm)
    _count_the_serving(vv, task, vehicle_id=vehicle_id, arrival=arrival, vvm=vvm)
    journal_append(vv, entry, vvm)
    vv.pending = None
    if advance:
        _advance_locked(vv, vvm, before=before)
    else:
        vv_save_changes(vv, before)
    return True


def _held_answer(
    task_id: int,
    vv_id: uuid.UUID,
    *,
    vehicle_id: int | None,
    q: int | None,
    now: float,
    readings: list[dict[str, Any]],
    failure: str | None,
) -> tuple[VirtualVehicle, PendingRequest, Task] | None:
    """The VV held until the transaction ends and its task answered, when the VV waits for
    that answer (on this RV): the VV, its request and the task; None when it does not.

    The VV first, then its task: the order every service takes them in, so two workers cannot
    deadlock. When the caller knows the task's request (``q``, the RV's loop does), both go to
    the database at once and their answers come back together; should the VV then not be
    waiting for that answer here, _NotAnswered rolls the task's update back with the
    transaction."""

    def answer(request: int) -> Callable[[], Task | None]:
        return take_answer(
            task_id,
            vv_id,
            q=request,
            vehicle_id=vehicle_id,
            now=now,
            readings=[] if failure is not None else readings,
            status=TaskStatus.DONE if failure is None else TaskStatus.REJECTED,
        )

    read_vv = locked_vv_later(vv_id)
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
        return None
    task = (read_task or answer(pending.q))()
    return None if task is None else (vv, pending, task)


def _answer_entry(
    vv: VirtualVehicle,
    task: Task,
    pending: PendingRequest,
    readings: list[dict[str, Any]],
    *,
    failure: str | None,
    now: float,
    vvm: VVM,
) -> dict[str, Any]:
    """The journal entry that answers the VV's request with the task's readings (or rejects
    it: ``failure``), and those who hear of it: the live map, the VVs its class holds back,
    the customer's webhooks; a reading's pictures are the customer's from now on."""
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
        vv_notify(vv=vv, event=NotifyEvent.TASK_DONE, vvm=vvm, at_ms=time_ms, task_id=task.pk)
    return entry


def _count_the_serving(
    vv: VirtualVehicle,
    task: Task,
    *,
    vehicle_id: int | None,
    arrival: VehicleState | None,
    vvm: VVM,
) -> None:
    """The RV that served the task: its reports (where it stopped: ``arrival``, or what this
    process's fleet kept for it) recorded with the answer, and its count of tasks done; the
    VV's host is where the VV leaves from."""
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
    elif task.vehicle_id is not None:
        Vehicle.objects.filter(pk=task.vehicle_id).update(tasks_done=F("tasks_done") + 1)


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
    logger.warning("reading failed", extra={**about(vv), "reason": failure})
    return answer_reject(pending, time_ms=vvm.clock.epoch_ms(now), message=message)


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
            slot_freed(vv, vvm)
    logger.info("vv cancelled", extra={"vv": str(vv_id)})
    return True
