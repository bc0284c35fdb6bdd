"""A VV's step: run its program to its next blocking call (``vvm.runtime``, from the journal)
and apply what it did (storage writes, log lines, the tasks it asked for), or say why the
platform could not (StepBroke, which ends the VV). ``vvs`` decides when a VV steps and what
happens to its request next.
"""

from __future__ import annotations

import json

from django.db.models import JSONField, Value

from cpcc_site import database
from missions.events import task_event
from missions.models import (
    LogEntry,
    StorageDocument,
    Task,
    VirtualVehicle,
)
from vvm_worker.runtime import (
    ErrorKind,
    Outcome,
    PendingRequest,
    StepInput,
    StepResult,
    VVError,
)
from vvm_worker.runtime.types import Effect
from vvm_worker.runtime.v8 import V8Closed
from vvm_worker.services.base import (
    VVM,
    logger,
    pending_json,
)
from vvm_worker.services.customers import customer_limits
from vvm_worker.services.journal import JournalView, journal_full
from vvm_worker.services.store import (
    StepBroke,
    effects_write,
    rows_add,
)
from vvm_worker.services.values import Unstorable, check_text, json_value

_KEY_CHARS = StorageDocument._meta.get_field("key").max_length or 0
_SHOWN_KEY_CHARS = 40  # of a key quoted in an error
_JSON_NULL = Value(None, JSONField())


def step_and_apply(*, vv: VirtualVehicle, vvm: VVM) -> StepResult:
    """Run the VV's next step and apply what it did. Raises StepBroke when that fails for any
    other reason than a database outage or a process that stops (both leave the step to be
    done again)."""
    try:
        return _run_step(vv, vvm)
    except Exception as exc:
        if isinstance(exc, V8Closed) or database.is_outage(exc):
            raise
        raise StepBroke(exc) from exc


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
        logger.warning("vv step refused: %s", refused, extra=about(vv))
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
    effects_write(vv, stored=stored, removed=removed, lines=lines)
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


def about(vv: VirtualVehicle) -> dict[str, str | None]:
    """What a log line about a VV names: the VV, its customer and the RV it is on."""
    rv = vv.host_rv
    return {"vv": str(vv.id), "customer": vv.customer.slug, "vehicle": rv and rv.name}


def new_tasks_of(*, vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> list[Task] | None:
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
    tasks_save(vv=vv, tasks=new, vvm=vvm)
    return None


def tasks_save(*, vv: VirtualVehicle, tasks: list[Task] | None, vvm: VVM) -> None:
    """Save the new ones of these tasks (as routing left them: on an RV's list, or rejected)."""
    new = [t for t in tasks or () if t.pk is None]
    if new:
        rows_add(new)  # their keys are read by the end of the unit of work
        vvm.announce_at_commit(lambda: [task_event(task, vv.customer_id) for task in new])
