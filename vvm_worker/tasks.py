"""Celery tasks: the messages between hosts. They carry ids only; the database holds the state.

Every task is safe to run twice (``acks_late``: Celery delivers at least once) and returns only
after its work is committed, so a worker that dies mid-task leaves the message to be delivered
again, and a worker that restarts recovers from the database anyway. A database outage is
waited out and the work done again, the message unacknowledged meanwhile.
"""

from __future__ import annotations

import uuid
from typing import Any

from celery import shared_task
from django.conf import settings

from cpcc_site import database
from vvm_worker.delivery import NOTIFY_QUEUE, NOTIFY_TASK, WEBHOOK_DELIVER_TASK, PerKeyLimit
from vvm_worker.dispatch import ADMIT_TASK, VEHICLE_CHANGED_TASK, VV_ADVANCE_TASK
from vvm_worker.hosts import current_host
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_admit_queued
from vvm_worker.services import vv_advance as advance
from vvm_worker.services.notifications import WebhookJob, vv_event_fan_out, webhook_attempt


@shared_task(name=VV_ADVANCE_TASK, acks_late=True, ignore_result=True)
def vv_advance(vv_id: str) -> None:
    """The VV arrived on one of this worker's hosts (or must be looked at again): step and
    route it (an RV worker does it on its host thread, whichever of its vehicles it is on)."""
    host = current_host()
    if host is None:
        database.through_outages(lambda: advance(vv_id=uuid.UUID(vv_id), vvm=platform_vvm()))
    else:
        database.through_outages(lambda: host.advance(uuid.UUID(vv_id)))


@shared_task(name=VEHICLE_CHANGED_TASK, acks_late=True, ignore_result=True)
def vehicle_changed(vehicle_id: int) -> None:
    """A vehicle of this worker has new work or a new status: its control loop re-plans."""
    host = current_host()
    if host is not None:
        host.wake(vehicle_id)


@shared_task(name=ADMIT_TASK, acks_late=True, ignore_result=True)
def admit(customer_id: int) -> None:
    """Start the customer's queued VVs as far as its quota allows (any ground station)."""
    host = current_host()  # a ground station's worker, or an RV worker that hosts one
    if host is not None:
        database.through_outages(lambda: host.admit(customer_id))
    else:
        database.through_outages(
            lambda: vv_admit_queued(customer_id=customer_id, vvm=platform_vvm())
        )


# --- notifications (the ``notify`` queue: vvm_worker/services/notifications.py) ---------------

# A customer's webhook POSTs at once in this process (``manage.py notifyworker``'s threads): a
# job beyond them goes back to the queue for a moment, its thread free for other customers.
_POSTING = PerKeyLimit(1)
# How soon a job that found its customer's POSTs all under way is tried again.
BUSY_AGAIN_S = 0.5


@shared_task(name=NOTIFY_TASK, acks_late=True, ignore_result=True)
def notify(event: str, vv_id: str, at_ms: int, task_id: int | None = None) -> None:
    """An event someone of the VV's customer listens for: e-mail the users who chose it, and
    hand each webhook that hears of it a delivery of its own."""
    jobs = database.through_outages(
        lambda: vv_event_fan_out(event=event, vv_id=uuid.UUID(vv_id), at_ms=at_ms, task_id=task_id)
    )
    for job in jobs:
        _deliver(job, attempt=1)


@shared_task(name=WEBHOOK_DELIVER_TASK, acks_late=True, ignore_result=True)
def webhook_deliver(job: dict[str, Any], attempt: int) -> None:
    """One attempt to POST an event to a webhook; a failed one (no answer, or not 2xx) is
    tried again later with back-off (CPCC_WEBHOOK_RETRY_S, doubling), CPCC_WEBHOOK_ATTEMPTS
    times in all."""
    parsed = WebhookJob(
        webhook_id=int(job["webhook_id"]),
        delivery=uuid.UUID(job["delivery"]),
        event=str(job["event"]),
        vv_id=uuid.UUID(job["vv_id"]),
        task_id=None if job["task_id"] is None else int(job["task_id"]),
        body=str(job["body"]),
        customer_id=None if job.get("customer_id") is None else int(job["customer_id"]),
    )
    customer = parsed.customer_id
    _POSTING.limit = settings.CPCC_NOTIFY_PER_CUSTOMER
    if not _POSTING.try_take(customer):
        _deliver(parsed, attempt=attempt, countdown_s=BUSY_AGAIN_S)  # (acknowledged: re-sent)
        return
    try:
        retry_in_s = database.through_outages(lambda: webhook_attempt(job=parsed, attempt=attempt))
    finally:
        _POSTING.give_back(customer)
    if retry_in_s is not None:
        _deliver(parsed, attempt=attempt + 1, countdown_s=retry_in_s)


def _deliver(job: WebhookJob, *, attempt: int, countdown_s: float = 0.0) -> None:
    args = [
        {
            "webhook_id": job.webhook_id,
            "delivery": str(job.delivery),
            "event": job.event,
            "vv_id": str(job.vv_id),
            "task_id": job.task_id,
            "body": job.body,
            "customer_id": job.customer_id,
        },
        attempt,
    ]
    webhook_deliver.apply_async(args=args, queue=NOTIFY_QUEUE, countdown=countdown_s or None)
