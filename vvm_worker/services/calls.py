"""The VVM-API calls a host answers itself: those answered at once (``VV.image.*`` and
``VV.message.send``, pending kind "call") and ``VV.message.receive`` (kind "message"), which
waits on a ground station for a message or its timeout.

Each answer is a journal entry written in the unit of work of the VV's step, with what the call
did (a message inserted, a picture saved), so a call is answered once however often the program
is replayed, and a replay reads the same answer. The CPU the host spends on a call counts
against the VV's CPU quota together with its steps (``VirtualVehicle.call_cpu_s``), so a loop
of calls is stopped by the quota as a loop of code is.
"""

from __future__ import annotations

import time
from typing import Any

from missions.models import VirtualVehicle
from vvm_worker.runtime import (
    ErrorKind,
    Limits,
    Outcome,
    PendingRequest,
    StepResult,
    VVError,
    answer_call,
    answer_call_error,
    answer_message,
)
from vvm_worker.services.base import VVM, logger
from vvm_worker.services.images import ImageCallError, image_call
from vvm_worker.services.journal import journal_append
from vvm_worker.services.messages import MessageError, message_send, vv_message_take
from vvm_worker.services.routing import vv_migrate_to_ground_station


def vv_answer_call(
    *, vv: VirtualVehicle, pending: PendingRequest, limits: Limits, vvm: VVM
) -> StepResult | None:
    """Answer the VV's pending call (kind "call") in its journal; the caller steps it again.
    Returns the outcome that ends the VV instead when the call took it over its CPU quota
    (the answer is journaled all the same: a replay finds it)."""
    op, args = pending.op or "", pending.args or {}
    time_ms = vvm.clock.epoch_ms(vvm.clock.now_s())
    started = time.thread_time()
    try:
        data = _call(vv, op, args, limits, vvm)
        entry = answer_call(pending, time_ms=time_ms, data=data)
    except MessageError as exc:
        entry = answer_call_error(pending, time_ms=time_ms, name="MessageError", message=str(exc))
    except ImageCallError as exc:
        entry = answer_call_error(pending, time_ms=time_ms, name="ImageError", message=str(exc))
    vv.call_cpu_s += time.thread_time() - started
    journal_append(vv, entry, vvm)
    vv.pending = None
    if vv.call_cpu_s <= limits.cpu_s:
        return None
    logger.info("vv over its CPU quota in a call", extra={"vv": str(vv.id), "call": op})
    error = VVError(
        ErrorKind.QUOTA,
        f"the VV used more than {limits.cpu_s:g} s of CPU time in one step, its calls of "
        "VV.image and VV.message.send included (quota: CPU time per step)",
        pending.line,
        pending.column,
        quota="cpu",
    )
    return StepResult(Outcome.KILLED, error=error)


def _call(vv: VirtualVehicle, op: str, args: dict[str, Any], limits: Limits, vvm: VVM) -> Any:
    if op == "message.send":
        message = message_send(
            customer_id=vv.customer_id,
            sender=vv,
            to=str(args.get("to", "")),
            value_json=str(args.get("value", "null")),
            max_bytes=limits.message_bytes,
            vvm=vvm,
        )
        return {"id": message.pk}
    if op.startswith("image."):
        return image_call(vv=vv, op=op, args=args, limits=limits)
    raise ValueError(f"unknown VVM-API call {op!r}")  # the prelude makes no other


def vv_answer_receive(*, vv: VirtualVehicle, pending: PendingRequest, vvm: VVM) -> bool:
    """Answer the VV's pending ``receive`` (kind "message") with the oldest message not taken
    yet, or with null once its timeout has passed: True, and the caller steps it again.
    Otherwise the VV waits (False): on a ground station, where a message (the sender's
    ``vv_arrived``) or a timer at its timeout wakes it; a VV aboard an RV moves to one
    first, so that nothing of it is on a vehicle that flies for others."""
    now = vvm.clock.now_s()
    state = dict(vv.pending or {})
    until = state.get("until_s")
    if until is None:
        until = now + float(pending.timeout_s or 0.0)
        vv.pending = {**state, "until_s": until}
    message = vv_message_take(vv=vv, vvm=vvm)
    if message is None and now < until:
        if vv.host_rv is not None:  # (with no ground station at all, it waits aboard)
            vv_migrate_to_ground_station(vv=vv, reason="waiting for a message", vvm=vvm)
        vvm.dispatcher.vv_wake_later(vv.pk, until - now)
        return False
    entry = answer_message(pending, time_ms=vvm.clock.epoch_ms(now), message=message)
    journal_append(vv, entry, vvm)
    vv.pending = None
    if message is not None:
        logger.info("vv received a message", extra={"vv": str(vv.id), "from": message["id"]})
    return True
