"""The VVs' store: how a VV's unit of work reads and writes the database, by intent (a held
VV, a task's answer, a step's effects, the VV's changed columns), behind which sit the SQL
mechanics: statements compiled once (``cpcc_site.prepared``), writes sent without waiting in
a pipelined transaction, a fenced UPDATE that answers a task and gives back what the answer
needs. The services of a VV's life (``vvs``) say what happens; this module says how it is
kept. It is the only service module that writes SQL by hand or uses the prepared statements
of the task path.
"""

from __future__ import annotations

import contextlib
import functools
import uuid
from collections.abc import Callable, Iterator
from typing import Any

from django.db import DatabaseError, connection

from cpcc_site import database
from cpcc_site.prepared import (
    PreparedRead,
    deferred,
    insert_rows,
    pipelined_transaction,
    save_fields,
    send_later,
)
from missions.models import LogEntry, StorageDocument, Task, TaskStatus, VirtualVehicle


class StepBroke(Exception):
    """The platform could not run a VV's step or apply its result: a bug of the platform (not
    a database outage), which would happen again on every retry."""

    def __init__(self, cause: Exception) -> None:
        super().__init__(f"{type(cause).__name__}: {cause}")
        self.cause = cause


@contextlib.contextmanager
def unit_of_work() -> Iterator[None]:
    """A VV's unit of work: one transaction, pipelined. A statement the database refuses
    (a platform bug: a step's writes are checked before they are sent; a deferred one is
    refused at the next statement that waits, or when the block ends) raises StepBroke, as a
    step the platform cannot apply does; a database outage is raised as it is, for the
    caller to wait out and redo."""
    try:
        with pipelined_transaction():
            yield
    except DatabaseError as exc:
        if database.is_outage(exc):
            raise
        raise StepBroke(exc) from exc


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


def locked_vv(vv_id: uuid.UUID) -> VirtualVehicle | None:
    """The VV's row with its customer and hosts, held until the transaction ends."""
    return _LOCKED_VV.first(vv_id)


def locked_vv_later(vv_id: uuid.UUID) -> Callable[[], VirtualVehicle | None]:
    """``locked_vv``, sent now and read by the function it gives back (in a pipelined unit of
    work, with what is sent in between)."""
    return _LOCKED_VV.first_later(vv_id)


# A VV's open tasks (SQL written once: read for every VV that ends).
_OPEN_TASKS = PreparedRead(
    lambda vv_id: Task.objects.filter(vv_id=vv_id, status=TaskStatus.OPEN),
    samples=[("vv_id", uuid.UUID(int=0))],
)


def open_tasks_of(vv_id: uuid.UUID) -> list[Task]:
    """The VV's open tasks."""
    return _OPEN_TASKS.all(vv_id)


def take_answer(
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
    """``take_answer``'s statement, written once per database and fence."""
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


def vv_row(vv: VirtualVehicle) -> tuple[Any, ...]:
    """The VV's columns that advancing it may change, as they are now (``vv_save_changes``)."""
    return tuple(getattr(vv, name) for name in _ADVANCED_FIELDS)


def vv_save_changes(vv: VirtualVehicle, before: tuple[Any, ...]) -> None:
    """One UPDATE of the VV's row: the advanced columns that changed, and ``updated``."""
    changed = [
        name.removesuffix("_id")
        for name, old, new in zip(_ADVANCED_FIELDS, before, vv_row(vv), strict=True)
        if old != new
    ]
    with deferred():  # the unit holds the row: nothing to check, it may commit at once
        save_fields(vv, [*changed, "updated"], held=True)  # no VV signals: compiled once


def effects_write(
    vv: VirtualVehicle,
    *,
    stored: list[StorageDocument],
    removed: list[str],
    lines: list[LogEntry],
) -> None:
    """A step's effects: its storage writes (``stored`` upserted by key, ``removed`` keys
    deleted) and its log lines. The rows were checked before (``vvs._storable``): the writes
    go without waiting, their answers checked by the end of the unit of work."""
    if removed:
        StorageDocument.objects.filter(vv=vv, key__in=removed).delete()
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


def tasks_write(tasks: list[Task]) -> None:
    """Insert new tasks; their keys are read by the end of the unit of work."""
    with deferred():
        insert_rows(tasks)
