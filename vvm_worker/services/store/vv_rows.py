"""A VV's rows in the store: the held VV, its tasks, a task's answer (a fenced UPDATE that
gives back what the answer needs), a step's effects, the VV's changed columns, why it waits
and when its RV expects to reach its next task."""

from __future__ import annotations

import functools
import uuid
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from django.db import connection
from django.db.models import Case, FloatField, Value, When

from cpcc_site.prepared import PreparedRead, deferred, insert_rows, save_fields, send_later
from missions.models import LogEntry, StorageDocument, Task, TaskStatus, VirtualVehicle

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


# A VV's open tasks of one request, by index (a VV that arrives with its request made).
_REQUEST_TASKS = PreparedRead(
    lambda vv_id, q: Task.objects.filter(vv_id=vv_id, q=q, status=TaskStatus.OPEN).order_by(
        "index"
    ),
    samples=[("vv", uuid.UUID(int=0)), ("q", 7_654_321)],
)


def request_tasks_of(vv_id: uuid.UUID, q: int) -> list[Task]:
    """The VV's open tasks of its request ``q``, by index."""
    return _REQUEST_TASKS.all(vv_id, q)


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
        return None if row is None else _answered(row, task_id, vv_id, q, status, now, readings)

    return read


def _answered(
    row: tuple[Any, ...],
    task_id: int,
    vv_id: uuid.UUID,
    q: int,
    status: TaskStatus,
    now: float,
    readings: list[dict[str, Any]],
) -> Task:
    """The task ``take_answer`` answered, from what its UPDATE gave back."""
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


def vv_fields_save(vv: VirtualVehicle, fields: Sequence[str], *, note: LogEntry) -> None:
    """These columns of the held VV as they are now, and a line in its log (``note``), sent
    without waiting (a refusal fails the unit of work)."""
    with deferred():
        save_fields(vv, fields, held=True)
        insert_rows([note])


def next_task_etas_write(etas: Mapping[uuid.UUID, float]) -> set[uuid.UUID]:
    """Write each VV's ``next_task_eta_s`` where no other transaction holds its row; gives back
    the VVs written. On PostgreSQL one statement for all of them (the rows held elsewhere
    skipped: it never waits for a row); on SQLite, where a writer holds the whole database,
    one for as many as its limit of parameters allows."""
    if not etas:
        return set()
    ids = sorted(etas)
    if connection.vendor != "postgresql":
        # bulk_update's CASE, without the transaction it opens around its statements (a
        # BEGIN more, where one statement commits by itself); its batches: three parameters
        # an estimate (the IN's id, the WHEN's id, the value).
        batch = connection.ops.bulk_batch_size(["pk", "pk", "next_task_eta_s"], ids)
        for start in range(0, len(ids), batch):
            some = ids[start : start + batch]
            VirtualVehicle.objects.filter(pk__in=some).update(
                next_task_eta_s=Case(
                    *(When(pk=vv_id, then=Value(etas[vv_id])) for vv_id in some),
                    output_field=FloatField(),
                )
            )
        return set(ids)
    with connection.cursor() as cursor:
        cursor.execute(_etas_sql(), [ids, [etas[i] for i in ids], ids])
        return {row[0] for row in cursor.fetchall()}


@functools.cache
def _etas_sql() -> str:
    """``next_task_etas_write``'s statement on PostgreSQL: the rows nobody holds."""
    meta, quote = VirtualVehicle._meta, connection.ops.quote_name
    table, pk = quote(meta.db_table), quote(meta.pk.column)
    eta = quote(meta.get_field("next_task_eta_s").column)
    return (
        f"UPDATE {table} SET {eta} = e.eta FROM unnest(%s::uuid[], %s::double precision[]) "
        f"AS e(id, eta) WHERE {table}.{pk} = e.id AND {table}.{pk} IN (SELECT {pk} FROM {table} "
        f"WHERE {pk} = ANY(%s::uuid[]) FOR NO KEY UPDATE SKIP LOCKED) RETURNING {table}.{pk}"
    )
