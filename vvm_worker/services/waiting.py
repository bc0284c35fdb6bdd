"""Why a VV waits, as its owner reads it: parked on a ground station while no RV in service
covers its next task, or (CPCC_REQUIRE_PILOT) none of those in service has a pilot on duty
(routing starts and ends that, each with a line in the VV's log), and when the RV it is
aboard expects to reach its next task (that RV's control loop's plan).

The queue (a customer's limit of VVs in parallel) needs nothing here: a queued VV's place in
it is read when it is shown (``missions.waiting``).
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping

from missions.models import LogEntry, Task, VirtualVehicle, WaitReason
from missions.waiting import duration_text
from vvm_worker.services.base import VVM, customer_named, logger
from vvm_worker.services.store import next_task_etas_write, vv_fields_save

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


# What a VV waits for while the RVs in service that cover its next task have no pilot on duty
# (CPCC_REQUIRE_PILOT), in the customer's words (naming neither a vehicle nor a pilot).
NO_PILOT_MESSAGE = (
    "no pilot on duty for the vehicles that cover its next task; it continues when one comes "
    "on duty"
)


def vv_wait_start(*, vv: VirtualVehicle, task: Task, vvm: VVM, no_pilot: bool = False) -> None:
    """The VV waits for an RV in service that covers its next task ``task``: routing parks it
    on a ground station because only RVs out of service (maintenance, charging, a worker that
    is gone) could serve it, or, with ``no_pilot``, RVs in service with no pilot on duty
    (CPCC_REQUIRE_PILOT). Its row says so and its log gets ``waiting: ...``; a VV that
    already waits so is left alone (nothing is written: routing looks at it again at every
    fleet change). The caller holds the VV's row."""
    if no_pilot:
        reason, message = WaitReason.NO_PILOT, NO_PILOT_MESSAGE
    else:
        reason, message = WaitReason.NO_VEHICLE, no_vehicle_message(task)
    if vv.waiting_reason == reason and vv.waiting_message == message:
        return
    now = vvm.clock.now_s()
    if not vv.waiting_reason:
        vv.waiting_since_s = now
    vv.waiting_reason, vv.waiting_message = reason, message
    note = LogEntry(vv=vv, at_s=now, level=PLATFORM_NOTE, message=f"waiting: {message}")
    vv_fields_save(vv, WAITING_FIELDS, note=note)
    logger.info(
        "vv waits: %s",
        "no pilot on duty for the RVs that cover its next task"
        if no_pilot
        else "no vehicle in service covers its next task",
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
    note = LogEntry(vv=vv, at_s=now, level=PLATFORM_NOTE, message=f"continues: waited {waited}")
    vv_fields_save(vv, WAITING_FIELDS, note=note)
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
    another's."""
    written = next_task_etas_write(etas)
    return {vv_id: eta for vv_id, eta in etas.items() if vv_id not in written}
