"""What a VV that has not ended waits for, in its owner's words (the VV's page, the API's
``waiting`` and the CLI show it), never naming a vehicle or another customer:

- ``no_vehicle``: no RV in service covers its next task (routing parked it on a ground
  station and keeps the reason on its row, ``vvm_worker.services.waiting``);
- ``no_pilot``: the RVs in service that cover its next task have no pilot on duty, where the
  provider requires one (CPCC_REQUIRE_PILOT; kept on its row as ``no_vehicle`` is);
- ``queue``: it waits in its customer's queue behind the customer's other VVs (its place is
  read when it is shown: it changes whenever one of them ends);
- ``service_level``: it is queued and admission holds it back while another service class
  misses its target and its customer's keeps its own with room to spare (admission keeps the
  reason on its row, ``vvm_worker.services.admission``);
- ``flying``: it is aboard an RV with an open task, which its RV's plan expects to reach at
  ``next_task_eta_s`` (written by the RV's control loop when its plan changes);
- ``message``: its program waits in ``VV.message.receive`` (its pending request, kind
  "message", says until when: ``vvm_worker.services.calls``).
"""

from __future__ import annotations

import datetime as dt
import uuid
from collections.abc import Sequence
from dataclasses import dataclass

from django.db.models import Count, FloatField, IntegerField, OuterRef, Q, QuerySet, Subquery
from django.db.models.fields.json import KT
from django.db.models.functions import Cast, Coalesce
from django.utils import timezone

from missions.models import ACTIVE_STATUSES, VirtualVehicle, VVStatus, WaitReason

# An estimate this far in the past is not shown (the RV is late, or has not planned since).
ETA_STALE_S = 60.0


@dataclass(frozen=True)
class QueuePlace:
    """A queued VV's place: its customer's VVs running now, those queued before it, and the
    customer's limit of VVs in parallel."""

    running: int
    before: int
    limit: int

    @property
    def ahead(self) -> int:
        """How many of the customer's VVs go first: those running and those queued before."""
        return self.running + self.before


@dataclass(frozen=True)
class Waiting:
    """Why a VV waits: ``reason`` (a WaitReason value), ``message`` (the customer's words),
    ``since_s`` (platform clock, None when not known) and ``next_task_eta_s`` (seconds from
    now until its RV reaches its next task, by its plan; None when not known)."""

    reason: str
    message: str
    since_s: float | None = None
    next_task_eta_s: float | None = None


def duration_text(seconds: float) -> str:
    """A wait as a person says it: "40 s", "12 min", "2 h 5 min"."""
    whole = max(0, round(seconds))
    if whole < 120:
        return f"{whole} s"
    minutes = round(whole / 60)
    if minutes < 120:
        return f"{minutes} min"
    return f"{minutes // 60} h {minutes % 60} min"


def queue_message(place: QueuePlace) -> str:
    if place.ahead < place.limit:
        return "in the queue, about to start"
    return f"in the queue behind {place.ahead} of your VVs (limit {place.limit} in parallel)"


def flying_message(eta_s: float | None) -> str:
    if eta_s is None:
        return "flying to your task"
    return f"flying to your task, about {duration_text(eta_s)}"


def message_wait_message(left_s: float | None) -> str:
    if left_s is None:
        return "waiting for a message"
    return f"waiting for a message, at most {duration_text(max(0.0, left_s))} more"


def with_message_wait(vvs: QuerySet[VirtualVehicle]) -> QuerySet[VirtualVehicle]:
    """The VVs, each with what ``vv_waiting`` needs of a pending ``VV.message.receive``
    (``pending_kind``, ``pending_until_s``, ``pending_timeout_s``), read from the row's
    pending request without reading the request itself (a list reads only some columns, and
    a batch of tasks makes a large one)."""
    return vvs.annotate(
        pending_kind=KT("pending__kind"),
        pending_until_s=Cast(KT("pending__until_s"), FloatField()),
        pending_timeout_s=Cast(KT("pending__timeout_s"), FloatField()),
    )


def _message_wait(vv: VirtualVehicle) -> tuple[bool, float | None, float | None]:
    """Whether the VV waits in ``VV.message.receive``, until when (platform clock, None
    before the host has looked for a message) and how long it said it would wait."""
    if hasattr(vv, "pending_kind"):  # a list's row (with_message_wait)
        kind, until_s, timeout_s = vv.pending_kind, vv.pending_until_s, vv.pending_timeout_s
    else:
        pending = vv.pending if isinstance(vv.pending, dict) else {}
        kind, until_s, timeout_s = (
            pending.get("kind"),
            pending.get("until_s"),
            pending.get("timeout_s"),
        )
    if kind != "message":
        return False, None, None
    return (
        True,
        None if until_s is None else float(until_s),
        None if timeout_s is None else float(timeout_s),
    )


def platform_now_s(vv: VirtualVehicle, now: dt.datetime | None = None) -> float:
    """Now (or ``now``) on the VV's platform clock: the Unix epoch in a live system, the
    scenario's seconds in ``simulate`` (``VirtualVehicle.platform_datetime``)."""
    return (now or timezone.now()).timestamp() - vv.platform_offset_s


def vv_waiting(
    vv: VirtualVehicle,
    *,
    tasks_open: int,
    place: QueuePlace | None = None,
    now: dt.datetime | None = None,
) -> Waiting | None:
    """What the VV waits for now, or None (it has ended, or runs without waiting).
    ``tasks_open``: its open tasks; ``place``: its place in the queue when it is queued
    (``queue_places``; read here if not given)."""
    if vv.is_ended:
        return None
    if vv.status == VVStatus.QUEUED:
        if vv.waiting_reason == WaitReason.SERVICE_LEVEL:
            return Waiting(vv.waiting_reason, vv.waiting_message, since_s=vv.waiting_since_s)
        if place is None:
            place = queue_places(vvs=[vv])[vv.pk]
        return Waiting(WaitReason.QUEUE, queue_message(place), since_s=vv.submitted_s)
    receiving, until_s, timeout_s = _message_wait(vv)
    if receiving:
        if until_s is None:
            return Waiting(WaitReason.MESSAGE, message_wait_message(None))
        since_s = None if timeout_s is None else until_s - timeout_s
        left_s = until_s - platform_now_s(vv, now)
        return Waiting(WaitReason.MESSAGE, message_wait_message(left_s), since_s=since_s)
    if vv.waiting_reason:
        return Waiting(vv.waiting_reason, vv.waiting_message, since_s=vv.waiting_since_s)
    if vv.host_rv_id is None or tasks_open <= 0:
        return None
    eta_s = None
    if vv.next_task_eta_s is not None:
        left_s = vv.next_task_eta_s - platform_now_s(vv, now)
        eta_s = None if left_s < -ETA_STALE_S else float(max(0, round(left_s)))
    return Waiting(WaitReason.FLYING, flying_message(eta_s), next_task_eta_s=eta_s)


def queue_places(*, vvs: Sequence[VirtualVehicle]) -> dict[uuid.UUID, QueuePlace]:
    """The places of the queued ones of these VVs in their customers' queues (in the order
    admission takes them: submitted_s, created, id): one statement for all of them, none
    when none is queued."""
    queued = [vv.pk for vv in vvs if vv.status == VVStatus.QUEUED]
    if not queued:
        return {}
    mine = VirtualVehicle.objects.filter(customer_id=OuterRef("customer_id")).order_by()
    running = (
        mine.filter(status__in=ACTIVE_STATUSES)
        .values("customer_id")
        .annotate(n=Count("pk"))
        .values("n")
    )
    earlier = (
        Q(submitted_s__lt=OuterRef("submitted_s"))
        | Q(submitted_s=OuterRef("submitted_s"), created__lt=OuterRef("created"))
        | Q(submitted_s=OuterRef("submitted_s"), created=OuterRef("created"), pk__lt=OuterRef("pk"))
    )
    before = (
        mine.filter(earlier, status=VVStatus.QUEUED)
        .values("customer_id")
        .annotate(n=Count("pk"))
        .values("n")
    )
    rows = (
        VirtualVehicle.objects.filter(pk__in=queued)
        .order_by()
        .annotate(
            running_n=Coalesce(Subquery(running, output_field=IntegerField()), 0),
            before_n=Coalesce(Subquery(before, output_field=IntegerField()), 0),
        )
        .values_list("pk", "running_n", "before_n", "customer__max_parallel_vvs")
    )
    return {pk: QueuePlace(running, before, limit) for pk, running, before, limit in rows}
