"""Why a VV waits, as its owner reads it: parked on a ground station while no RV in service
covers its next task (routing starts and ends that, each with a line in the VV's log), and
when the RV it is aboard expects to reach its next task (that RV's control loop's plan).

The queue (a customer's limit of VVs in parallel) needs nothing here: a queued VV's place in
it is read when it is shown (``missions.waiting``).
"""

from __future__ import annotations

import functools
import uuid
from collections.abc import Mapping

from django.db import connection
from django.db.models import Case, FloatField, Value, When

from cpcc_site.prepared import deferred, insert_rows, save_fields
from missions.models import LogEntry, Task, VirtualVehicle, WaitReason
from missions.waiting import duration_text
from vvm_worker.services.base import VVM, customer_named, logger

# The level of the lines the platform adds to a VV's log (its program's lines are "info"):
# its owner, and a comparison of two runs, can tell them apart.
PLATFORM_NOTE = "platform"
# The VV's columns that say why it waits (written only when that changes).
WAITING_FIELDS = ("waiting_reason", "waiting_message", "waiting_since_s")


def no_vehicle_message(task: Task) -> str:
    """What a VV waits for while only RVs out of service cover its next task ``task``, in
    the customer's words (which never name a vehicle)."""
    return (
        f"no vehicle in service covers the next task at {task.lat:.6f}, {task.lng:.6f}, "
        f"{task.alt:g} m; it continues when one does"
    )


def vv_wait_start(*, vv: VirtualVehicle, task: Task, vvm: VVM) -> None:
    """The VV waits for an RV in service that covers its next task ``task``: routing parks it
    on a ground station because only RVs out of service (maintenance, charging, a worker that
    is gone) could serve it. Its row says so and its log gets ``waiting: ...``; a VV that
    already waits so is left alone (nothing is written: routing looks at it again at every
    fleet change). The caller holds the VV's row."""
    message = no_vehicle_message(task)
    if vv.waiting_reason == WaitReason.NO_VEHICLE and vv.waiting_message == message:
        return
    now = vvm.clock.now_s()
    if not vv.waiting_reason:
        vv.waiting_since_s = now
    vv.waiting_reason, vv.waiting_message = WaitReason.NO_VEHICLE, message
    with deferred():
        save_fields(vv, WAITING_FIELDS, held=True)
        insert_rows([LogEntry(vv=vv, at_s=now, level=PLATFORM_NOTE, message=f"waiting: {message}")])
    logger.info(
        "vv waits: no vehicle in service covers its next task",
        extra={"vv": str(vv.id), "customer": customer_named(vv), "task": task.pk},
    )


def vv_wait_end(*, vv: VirtualVehicle, vvm: VVM) -> None:
    """The VV that waited moves on (an RV in service took its task, or none ever can and it
    is rejected): its row no longer says why it waits and its log gets ``continues: waited
    N s``. Nothing for a VV that was not waiting. The caller holds the VV's row."""
    if not vv.waiting_reason:
        return
    now = vvm.clock.now_s()
    waited = duration_text(now - (vv.waiting_since_s if vv.waiting_since_s is not None else now))
    vv.waiting_reason, vv.waiting_message, vv.waiting_since_s = "", "", None
    with deferred():
        save_fields(vv, WAITING_FIELDS, held=True)
        insert_rows(
            [LogEntry(vv=vv, at_s=now, level=PLATFORM_NOTE, message=f"continues: waited {waited}")]
        )
    logger.info(
        "vv continues after waiting %s",
        waited,
        extra={"vv": str(vv.id), "customer": customer_named(vv)},
    )


def vvs_record_next_task_eta(*, etas: Mapping[uuid.UUID, float]) -> dict[uuid.UUID, float]:
    """When the RV that each of these VVs is aboard expects to reach its next task (platform
    clock seconds), as the RVs' control loops last planned it. Gives back the estimates not
    written because another transaction holds their VV's row (for the caller to try again):
    an estimate never waits for a row, so it never holds one VV's row while waiting for
    another's. On PostgreSQL one statement for all of them; on SQLite, where a writer holds
    the whole database and nothing is left, one for as many as its limit of parameters
    allows."""
    if not etas:
        return {}
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
        return {}
    with connection.cursor() as cursor:
        cursor.execute(_etas_sql(), [ids, [etas[i] for i in ids], ids])
        written = {row[0] for row in cursor.fetchall()}
    return {vv_id: eta for vv_id, eta in etas.items() if vv_id not in written}


@functools.cache
def _etas_sql() -> str:
    """``vvs_record_next_task_eta``'s statement on PostgreSQL: the rows nobody holds."""
    meta, quote = VirtualVehicle._meta, connection.ops.quote_name
    table, pk = quote(meta.db_table), quote(meta.pk.column)
    eta = quote(meta.get_field("next_task_eta_s").column)
    return (
        f"UPDATE {table} SET {eta} = e.eta FROM unnest(%s::uuid[], %s::double precision[]) "
        f"AS e(id, eta) WHERE {table}.{pk} = e.id AND {table}.{pk} IN (SELECT {pk} FROM {table} "
        f"WHERE {pk} = ANY(%s::uuid[]) FOR NO KEY UPDATE SKIP LOCKED) RETURNING {table}.{pk}"
    )
