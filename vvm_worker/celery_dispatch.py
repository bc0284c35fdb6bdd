"""The distributed platform's dispatcher: work handed to the hosts' Celery workers by message,
once the transaction that made it commits."""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable
from typing import Any

from django.db import transaction

from cpcc_site.celery import app
from missions.selectors import customer_has_queued_vv
from vvm_worker.delivery import NOTIFY_QUEUE, NOTIFY_TASK
from vvm_worker.dispatch import (
    ADMIT_TASK,
    SHARED_QUEUE,
    VEHICLE_CHANGED_TASK,
    VV_ADVANCE_TASK,
    HostRef,
    LocalHost,
    gs_queue,
    rv_queue,
)
from vvm_worker.services.store import vv_hosts

logger = logging.getLogger("cpcc.dispatch")


class CeleryDispatcher:
    """Hands work to the hosts' Celery workers, once the transaction that made it commits.

    A VV goes to the queue of the host it is on at that moment, a vehicle's wake-up to the
    vehicle's queue. ``local`` lets an RV worker do the work of its own vehicles in its own
    thread without a round trip through Redis (an RV resuming a VV it keeps, a VV moving
    between two vehicles of the worker, a re-plan after new work), and a ground station's
    worker the work of the VVs it takes (those it admits, those that stay on it).
    """

    def __init__(self, local: LocalHost | None = None) -> None:
        self.local = local

    def vv_arrived(self, vv_id: uuid.UUID, *, on: HostRef | None = None) -> None:
        transaction.on_commit(lambda: _safely(lambda v: self._send_vv(v, on=on), vv_id))

    def vv_wake_later(self, vv_id: uuid.UUID, delay_s: float) -> None:
        # Always by message (a local host has no timer of its own), to the host the VV is on
        # then; the worker holds it until it is due. Lost (a worker killed meanwhile), the
        # ground station's sweep finds the VV once its time has passed.
        delay = max(0.0, delay_s)
        transaction.on_commit(lambda: _safely(lambda v: self._send_vv(v, countdown=delay), vv_id))

    def vehicle_changed(self, vehicle_id: int) -> None:
        transaction.on_commit(lambda: _safely(self._send_vehicle, vehicle_id))

    def customer_slot_freed(self, customer_id: int) -> None:
        transaction.on_commit(lambda: _safely(_admit_if_queued, customer_id))

    def _send_vv(
        self, vv_id: uuid.UUID, countdown: float | None = None, on: HostRef | None = None
    ) -> None:
        # Where the transaction that just committed put the VV, when it said so; read
        # otherwise. (The read, right after that commit, says the same but for a move
        # committed in between, which sends a message of its own.)
        if on is None:
            hosts = vv_hosts(vv_id)
            if hosts is None:
                return
            gs_id, rv_id = hosts
        else:
            gs_id, rv_id = on.gs_id, on.rv_id
        local = self.local
        if (
            countdown is None
            and local is not None
            and (
                local.is_vehicle(rv_id) if rv_id is not None else gs_id and local.is_station(gs_id)
            )
        ):
            local.advance_later(vv_id)
            return
        queue = rv_queue(rv_id) if rv_id is not None else gs_queue(gs_id) if gs_id else SHARED_QUEUE
        app.send_task(VV_ADVANCE_TASK, args=[str(vv_id)], queue=queue, countdown=countdown)

    def _send_vehicle(self, vehicle_id: int) -> None:
        if self.local is not None and self.local.is_vehicle(vehicle_id):
            self.local.wake_later(vehicle_id)
            return
        app.send_task(VEHICLE_CHANGED_TASK, args=[vehicle_id], queue=rv_queue(vehicle_id))


def _admit_if_queued(customer_id: int) -> None:
    """Ask for the customer's admission if a VV of it is queued, looked at after the commit
    that freed the slot: a VV queued later asks for its own admission once it is committed,
    which then sees the slot free. (Most VVs that end leave nothing queued behind them: no
    message, no admission unit of work.)"""
    if customer_has_queued_vv(customer_id=customer_id):
        app.send_task(ADMIT_TASK, args=[customer_id], queue=SHARED_QUEUE)


def _safely(send: Callable[[Any], None], arg: Any) -> None:
    """Send a message; if the broker is unreachable, say so and go on: the state is committed,
    and the hosts' periodic sweeps find the work (a message is only a hint)."""
    try:
        send(arg)
    except Exception:
        logger.exception("could not hand work to a worker; the hosts' sweeps will find it")


class CeleryNotifier:
    """Tells the ``notify`` queue's workers of an event once the transaction that made it
    commits (vvm_worker/services/notifications.py: only events someone listens for come
    here)."""

    def vv_event(
        self, *, event: str, vv_id: uuid.UUID, at_ms: int, task_id: int | None = None
    ) -> None:
        args = [event, str(vv_id), at_ms, task_id]
        transaction.on_commit(lambda: _send_notify(args))


def _send_notify(args: list[Any]) -> None:
    """Send it; a broker that cannot be reached loses it (no sweep looks for events), which
    is said in the log: the VV's state is committed whatever happens to its notification."""
    try:
        app.send_task(NOTIFY_TASK, args=args, queue=NOTIFY_QUEUE)
    except Exception:
        logger.exception(
            "could not queue a notification: it is lost", extra={"event": args[0], "vv": args[1]}
        )
