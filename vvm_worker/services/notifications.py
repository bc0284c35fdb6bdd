"""Hearing when a VV ends: a customer's webhooks, a user's choice of e-mails, and what happens
when one of the events comes (``vv.finished``, ``vv.failed`` for a VV that failed or was
killed, ``task.done``).

The way of an event:

1. ``vv_notify`` (called by the services that end a VV or answer a task, in their
   transaction) looks at ``Customer.notify_events``, read with the VV: when nobody of the
   customer listens for the event, that is all it costs. Otherwise the VVM's notifier sends
   one message once the transaction commits (vvm_worker/delivery.py).
2. ``vv_event_fan_out`` (a worker on the ``notify`` queue) writes the event's JSON body once,
   e-mails the users who chose the event, and gives back one ``WebhookJob`` per webhook.
3. ``webhook_attempt`` POSTs a job's body, signed, records the attempt in the webhook's
   delivery log and says after how long to try again, if at all.

``Customer.notify_events`` is kept by the accounts' services (accounts/services.py), in the
transaction of every change of a webhook or of a user's e-mail choice, with the customer's row
held.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import uuid
from dataclasses import dataclass

from django.conf import settings
from django.core import mail

from accounts.models import NotifyEvent, User, Webhook, WebhookDelivery
from missions.models import Task, VirtualVehicle, VVStatus
from vvm_worker import delivery
from vvm_worker.services.base import VVM

logger = logging.getLogger("cpcc.notify")

EVENTS = tuple(NotifyEvent.values)
# The newest attempts kept per webhook: enough to see what went wrong this week.
DELIVERY_LOG_KEPT = 1_000
# One namespace for delivery ids: the same event to the same webhook has the same id, however
# often its message is delivered (receivers may drop a second POST by its X-CPCC-Delivery).
_DELIVERY_IDS = uuid.UUID("6f1c9a52-3f57-4c1e-9a4e-54d2b1b0c8a1")


# --- 1. the event (the services that end a VV or answer a task) -------------------------------


def vv_notify(
    *, vv: VirtualVehicle, event: str, vvm: VVM, at_ms: int, task_id: int | None = None
) -> None:
    """Tell whoever of the VV's customer listens for ``event`` (once the caller's transaction
    commits); nothing, and no query, when nobody does. ``vv.customer`` is read with the VV."""
    if event in vv.customer.notify_events:
        vvm.notifier.vv_event(event=event, vv_id=vv.pk, at_ms=at_ms, task_id=task_id)


def ended_event(status: str) -> str | None:
    """The event of a VV that ended with this status (None for one its owner cancelled)."""
    if status == VVStatus.FINISHED:
        return NotifyEvent.VV_FINISHED
    if status in (VVStatus.FAILED, VVStatus.KILLED):
        return NotifyEvent.VV_FAILED
    return None


# --- 2. the event's fan-out (a worker on the notify queue) -------------------------------------


@dataclass(frozen=True)
class WebhookJob:
    """One event to POST to one webhook: the same body (and delivery id) at every attempt."""

    webhook_id: int
    delivery: uuid.UUID
    event: str
    vv_id: uuid.UUID
    task_id: int | None
    body: str
    customer_id: int | None = None  # whose: the notify worker limits each customer's POSTs


def vv_event_fan_out(
    *, event: str, vv_id: uuid.UUID, at_ms: int, task_id: int | None = None
) -> list[WebhookJob]:
    """What an event becomes: an e-mail to each active user of the VV's customer who chose it
    (sent now; a mail server that fails is logged, not retried), and a job per webhook that
    hears of it. Nothing for a VV (or task) that is no longer there."""
    vv = VirtualVehicle.objects.select_related("customer").filter(pk=vv_id).first()
    task = None
    if task_id is not None:
        task = Task.objects.filter(pk=task_id, vv_id=vv_id).first()
        if task is None:
            return []
    if vv is None:
        return []
    body = event_body(event=event, vv=vv, at_ms=at_ms, task=task)
    _email(event, vv, body)
    webhooks = Webhook.objects.filter(customer_id=vv.customer_id).order_by("pk")
    return [
        WebhookJob(
            webhook_id=webhook.pk,
            delivery=uuid.uuid5(_DELIVERY_IDS, f"{webhook.pk}:{event}:{vv_id}:{task_id}"),
            event=event,
            vv_id=vv_id,
            task_id=task_id,
            body=json.dumps(body, separators=(",", ":"), ensure_ascii=False),
            customer_id=vv.customer_id,
        )
        for webhook in webhooks
        if event in webhook.events
    ]


def event_body(
    *, event: str, vv: VirtualVehicle, at_ms: int, task: Task | None = None
) -> dict[str, object]:
    """The JSON a webhook receives: ``event``, the VV's ``id``, ``name`` and ``status`` (as it
    is when the event is sent), ``time`` (when it happened, ISO 8601 UTC), the ``error`` (with
    ``error_line`` and ``error_column`` when known) of a VV that failed, and for ``task.done``
    the ``task``."""
    body: dict[str, object] = {
        "event": event,
        "id": str(vv.pk),
        "name": vv.name,
        "status": vv.status,
        "time": _iso(at_ms),
    }
    if event == NotifyEvent.VV_FAILED:
        body["error"] = vv.error
        if vv.error_line is not None:
            body["error_line"] = vv.error_line
            body["error_column"] = vv.error_column
    if task is not None:
        body["task"] = {
            "q": task.q,
            "index": task.index,
            "position": [task.lat, task.lng, task.alt],
            "sensors": task.sensors,
            "status": task.status,
            "done": _iso(at_ms),
        }
    return body


def _iso(at_ms: int) -> str:
    moment = dt.datetime.fromtimestamp(at_ms / 1000, tz=dt.UTC)
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


_SUBJECTS = {
    NotifyEvent.VV_FINISHED: "{name} finished",
    NotifyEvent.VV_FAILED: "{name} {status}",
    NotifyEvent.TASK_DONE: "{name}: a task was done",
}


def _email(event: str, vv: VirtualVehicle, body: dict[str, object]) -> None:
    users = User.objects.filter(customer_id=vv.customer_id, is_active=True).exclude(email="")
    recipients = [u.email for u in users.order_by("pk") if event in u.email_events]
    if not recipients:
        return
    subject = "[CPCC] " + _SUBJECTS[NotifyEvent(event)].format(name=vv.name, status=vv.status)
    lines = [f"{key}: {json.dumps(value, ensure_ascii=False)}" for key, value in body.items()]
    page = f"{settings.CPCC_SITE_URL.rstrip('/')}/vvs/{vv.pk}/"
    text = "\n".join([*lines, "", f"See it on the platform: {page}", "", _WHY])
    messages = [mail.EmailMessage(subject, text, to=[address]) for address in recipients]
    try:
        mail.get_connection().send_messages(messages)
    except Exception:  # the mail server's problem must not hold up the webhooks
        logger.exception(
            "could not send the notification e-mails",
            extra={"vv": str(vv.pk), "customer": vv.customer.slug, "event": event},
        )


_WHY = "You get this because you chose it on the platform's Notifications page."


# --- 3. one attempt to deliver (a worker on the notify queue) ----------------------------------


def webhook_attempt(*, job: WebhookJob, attempt: int) -> float | None:
    """POST the job's body to its webhook (attempt 1, 2, ...), signed with the webhook's
    secret, and record how it went in the webhook's delivery log. Returns after how many
    seconds to try again (None: it was delivered, cannot be, or it was the last attempt of
    ``CPCC_WEBHOOK_ATTEMPTS``).

    Safe to run twice: an attempt already recorded is not made again, nor one after the
    event was delivered; a webhook removed meanwhile is not tried.
    """
    webhook = Webhook.objects.filter(pk=job.webhook_id).first()
    if webhook is None:
        return None
    tried = WebhookDelivery.objects.filter(webhook=webhook, delivery=job.delivery)
    delivered = tried.filter(status_code__gte=200, status_code__lt=300)
    if tried.filter(attempt__gte=attempt).exists() or delivered.exists():
        return None
    raw = job.body.encode()
    answer = delivery.post(
        webhook.url,
        raw,
        {
            delivery.SIGNATURE_HEADER: delivery.sign(raw, webhook.secret),
            delivery.EVENT_HEADER: job.event,
            delivery.DELIVERY_HEADER: str(job.delivery),
        },
        timeout_s=settings.CPCC_WEBHOOK_TIMEOUT_S,
        allow_private=settings.CPCC_WEBHOOK_ALLOW_PRIVATE,
    )
    WebhookDelivery.objects.create(
        webhook=webhook,
        delivery=job.delivery,
        event=job.event,
        vv_id=job.vv_id,
        task_id=job.task_id,
        attempt=attempt,
        status_code=answer.status,
        error=answer.error[:300],
        duration_ms=answer.duration_ms,
    )
    _prune(webhook)
    last = answer.ok or answer.permanent or attempt >= settings.CPCC_WEBHOOK_ATTEMPTS
    logger.log(
        logging.INFO if answer.ok else logging.WARNING,
        "webhook delivered" if answer.ok else "webhook delivery failed",
        extra={
            "webhook": webhook.pk,
            "event": job.event,
            "vv": str(job.vv_id),
            "attempt": attempt,
            "status": answer.status,
            "error": answer.error,
            "retry": not last,
        },
    )
    if last:
        return None
    return delivery.retry_delay_s(attempt, first_s=settings.CPCC_WEBHOOK_RETRY_S)


def _prune(webhook: Webhook) -> None:
    """Keep the webhook's newest DELIVERY_LOG_KEPT attempts."""
    oldest_kept = (
        WebhookDelivery.objects.filter(webhook=webhook)
        .order_by("-id")
        .values_list("id", flat=True)[DELIVERY_LOG_KEPT - 1 : DELIVERY_LOG_KEPT]
    )
    ids = list(oldest_kept)
    if ids:
        WebhookDelivery.objects.filter(webhook=webhook, id__lt=ids[0]).delete()
