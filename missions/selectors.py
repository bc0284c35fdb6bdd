"""Reading VVs and their data, always scoped to the customer who asks.

Every selector that returns a VV's data takes the user and the VV's id and raises VVNotFound
both for a missing VV and for another customer's, so a caller cannot tell them apart.
"""

from __future__ import annotations

import datetime as dt
import uuid
from collections.abc import Sequence
from typing import Any, TypeVar

from django.db.models import Count, F, Model, Q, QuerySet, TextField, Window
from django.db.models.functions import Cast, RowNumber

from accounts.models import User
from cpcc_site.prepared import Many, PreparedPages, PreparedRead
from fleet.models import GroundStation, Vehicle, VehicleStatus
from missions.events import event_for, migration_event, task_event, vv_event
from missions.models import (
    ENDED_STATUSES,
    LogEntry,
    Message,
    Migration,
    StorageDocument,
    Task,
    TaskStatus,
    TrackPoint,
    VirtualVehicle,
    VVStatus,
)
from missions.readings import IMAGE_FILE, image_file, image_references
from missions.waiting import with_message_wait

M = TypeVar("M", bound=Model)


class VVNotFound(LookupError):
    """No such VV for this user: it does not exist or belongs to another customer."""


class StorageKeyNotFound(LookupError):
    """The VV has no such key in its storage."""


class ImageNotFound(LookupError):
    """No reading of this VV references an image of that name."""


def with_active_vv_count(queryset: QuerySet[M], *, name: str) -> QuerySet[M]:
    """Customers, vehicles or ground stations (staff data), each with the number of its VVs
    (the customer's, those aboard, those held) that have not ended, as attribute ``name``."""
    return queryset.annotate(**{name: Count("vvs", filter=~Q(vvs__status__in=ENDED_STATUSES))})


def _with_hosts() -> QuerySet[VirtualVehicle]:
    """VVs with their customer and hosts, as every read for a user gets them."""
    return VirtualVehicle.objects.select_related("customer", "host_gs", "host_rv")


def sees_every_vv(user: User) -> bool:
    """Staff who may read customers' VVs (superusers, fleet managers, support; not pilots)."""
    return bool(user.is_staff) and user.has_perm("missions.view_virtualvehicle")


def vv_list_for_user(*, user: User) -> QuerySet[VirtualVehicle]:
    """The VVs a user may see: staff who may read them (``sees_every_vv``) every VV, a
    customer's member their customer's."""
    qs = _with_hosts()
    if sees_every_vv(user):
        return qs
    if user.customer_id is None:
        return qs.none()
    return qs.filter(customer_id=user.customer_id)


# What a list of VVs shows (the API's VVSerializer): only these columns are read.
_LISTED = (
    "id", "name", "status", "host_gs_id", "host_rv_id", "error", "error_line", "error_column",
    "created", "finished", "host_gs__name", "host_rv__name",
    # What it waits for (``missions.waiting``), its times on the platform clock.
    "waiting_reason", "waiting_message", "waiting_since_s", "next_task_eta_s", "submitted_s",
    "start_ms",
)  # fmt: skip


def vvs_listed(vvs: QuerySet[VirtualVehicle]) -> QuerySet[VirtualVehicle]:
    """The VVs with only the columns a list shows (the hosts' names, not the customer, the
    program or the journal; of the pending request what ``vv_waiting`` needs). Their task
    counts come for one page at a time (``with_task_counts``): counted in the same query, a
    page would join every task of every VV of the customer, and so would the count of its
    VVs."""
    listed = vvs.select_related(None).select_related("host_gs", "host_rv").only(*_LISTED)
    return with_message_wait(listed)


# The pages of a VV list (``vvs_listed``, newest first), compiled once: staff's and a
# customer's user's, each for every VV or those of one status.
def _listed(customer_id: int | None, status: str | None) -> QuerySet[VirtualVehicle]:
    vvs = vvs_listed(VirtualVehicle.objects.all()).order_by("-created")
    if customer_id is not None:
        vvs = vvs.filter(customer_id=customer_id)
    return vvs if status is None else vvs.filter(status=status)


_STATUS_SAMPLE = "\x00status"
_LISTS = {
    (False, False): PreparedRead(lambda: _listed(None, None), samples=[]),
    (False, True): PreparedRead(
        lambda status: _listed(None, status), samples=[("status", _STATUS_SAMPLE)]
    ),
    (True, False): PreparedRead(
        lambda customer_id: _listed(customer_id, None), samples=[("customer_id", -1)]
    ),
    (True, True): PreparedRead(
        lambda customer_id, status: _listed(customer_id, status),
        samples=[("customer_id", -1), ("status", _STATUS_SAMPLE)],
    ),
}


def vv_pages_for_user(*, user: User, status: str | None = None) -> PreparedPages[VirtualVehicle]:
    """The VVs of ``vv_list_for_user`` as a list pages through them (``vvs_listed``, newest
    first), all of them or those of one status."""
    if sees_every_vv(user):
        customer: tuple[Any, ...] = ()
    elif user.customer_id is not None:
        customer = (user.customer_id,)
    else:
        return PreparedPages(None, ())
    wanted = () if status is None else (status,)
    return PreparedPages(_LISTS[(bool(customer), bool(wanted))], (*customer, *wanted))


def with_task_counts(vvs: Sequence[VirtualVehicle]) -> Sequence[VirtualVehicle]:
    """The VVs, each with ``tasks_done`` and ``tasks_open``: one statement for all of them."""
    counts = task_counts(vv_ids=[vv.pk for vv in vvs])
    for vv in vvs:
        vv.tasks_done, vv.tasks_open = counts.get(vv.pk, (0, 0))  # type: ignore[attr-defined]
    return vvs


# The tasks done and open of some VVs: a read of every list of VVs, compiled once for each
# number of VVs.
_TASK_COUNTS = PreparedRead(
    lambda vv_ids: (
        Task.objects.filter(vv_id__in=vv_ids)
        .order_by()
        .values("vv_id")
        .annotate(
            done=Count("pk", filter=Q(status=TaskStatus.DONE)),
            open=Count("pk", filter=Q(status=TaskStatus.OPEN)),
        )
        .values_list("vv_id", "done", "open")
    ),
    samples=[("vv", Many(lambda i: uuid.UUID(int=7_000_000 + i)))],
)


def task_counts(*, vv_ids: Sequence[uuid.UUID]) -> dict[uuid.UUID, tuple[int, int]]:
    """The tasks done and open of each of these VVs (none: not in the answer), counted in one
    statement."""
    if not vv_ids:
        return {}
    return {vv_id: (done, open_) for vv_id, done, open_ in _TASK_COUNTS.rows(list(vv_ids))}


# The read of every API request about one VV (``vv_get_for_user``), compiled once: staff's,
# and a customer's user's (the customer in the WHERE, as ``vv_list_for_user`` scopes it).
_ANY_VV = PreparedRead(
    lambda pk: _with_hosts().order_by().filter(pk=pk), samples=[("pk", uuid.UUID(int=0))]
)
_CUSTOMERS_VV = PreparedRead(
    lambda pk, customer_id: _with_hosts().order_by().filter(pk=pk, customer_id=customer_id),
    samples=[("pk", uuid.UUID(int=0)), ("customer_id", -1)],
)


_QUEUED = PreparedRead(
    lambda customer_id: VirtualVehicle.objects.filter(
        customer_id=customer_id, status=VVStatus.QUEUED
    ).values_list("pk")[:1],
    samples=[("customer_id", -5_000_001)],
)


def customer_has_queued_vv(*, customer_id: int) -> bool:
    """Whether a VV of the customer waits to be admitted (SQL written once: asked whenever a
    slot may have freed)."""
    return bool(_QUEUED.rows(customer_id))


def vv_get_for_user(*, user: User, vv_id: uuid.UUID | str) -> VirtualVehicle:
    """One VV the user may see (``vv_list_for_user``); VVNotFound both for a missing VV and
    another customer's, and for an id that is no UUID at all."""
    try:
        pk = uuid.UUID(str(vv_id))
    except (ValueError, TypeError):
        raise VVNotFound(str(vv_id)) from None
    if sees_every_vv(user):
        vv = _ANY_VV.first(pk)
    elif user.customer_id is not None:
        vv = _CUSTOMERS_VV.first(pk, user.customer_id)
    else:
        vv = None
    if vv is None:
        raise VVNotFound(str(vv_id))
    return vv


def vv_tasks_for_user(*, user: User, vv_id: uuid.UUID | str) -> QuerySet[Task]:
    """The VV's tasks in the order it asked for them (request, then index in a batch)."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    # Through the VV's manager: each task's ``vv`` is this VV, without a join.
    return vv.tasks.select_related("vehicle").order_by("q", "index")


def vv_log_for_user(*, user: User, vv_id: uuid.UUID | str) -> QuerySet[LogEntry]:
    """The VV's log lines, oldest first."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    return vv.log.order_by("at_s", "seq", "id")  # each line's ``vv`` is this VV


def vv_storage_for_user(*, user: User, vv_id: uuid.UUID | str) -> QuerySet[StorageDocument]:
    """The VV's storage documents, by key."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    return vv.storage.order_by("key")  # each document's ``vv`` is this VV


def vv_track_for_user(*, user: User, vv_id: uuid.UUID | str) -> QuerySet[TrackPoint]:
    """Where the VV was while RVs carried it (the map's green line), oldest point first."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    return vv.track.order_by("t_s", "id")  # each point's ``vv`` is this VV


# The pages of a VV's log and storage, compiled once (the VV is read first, for the user).
_LOG_PAGES = PreparedRead(
    lambda vv_id: LogEntry.objects.filter(vv_id=vv_id).order_by("at_s", "seq", "id"),
    samples=[("vv", uuid.UUID(int=0))],
)
_STORAGE_PAGES = PreparedRead(
    lambda vv_id: StorageDocument.objects.filter(vv_id=vv_id).order_by("key"),
    samples=[("vv", uuid.UUID(int=0))],
)


def vv_log_pages_for_user(*, user: User, vv_id: uuid.UUID | str) -> PreparedPages[LogEntry]:
    """``vv_log_for_user`` as a list pages through it (each line's ``vv`` is the VV)."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    return PreparedPages(_LOG_PAGES, (vv.pk,), each=lambda entry: setattr(entry, "vv", vv))


def vv_storage_pages_for_user(
    *, user: User, vv_id: uuid.UUID | str
) -> PreparedPages[StorageDocument]:
    """``vv_storage_for_user`` as a list pages through it (each document's ``vv`` is the VV)."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    return PreparedPages(_STORAGE_PAGES, (vv.pk,), each=lambda doc: setattr(doc, "vv", vv))


# The pages of a VV's messages, in and out, newest first (one statement written once, its
# keys the VV as recipient and as sender): only what a message shows, and of its recipient
# (another VV of the customer's, for one that went out) the name and what its platform clock
# needs, never its program or journal.
_MESSAGE_FIELDS = (
    "id", "sender_id", "sender_name", "recipient_id", "value", "bytes", "sent_s", "received_s",
    "recipient__name", "recipient__start_ms", "recipient__submitted_s",
)  # fmt: skip
_MESSAGE_PAGES = PreparedRead(
    lambda recipient_id, sender_id: (
        Message.objects.filter(Q(recipient_id=recipient_id) | Q(sender_id=sender_id))
        .select_related("recipient")
        .only(*_MESSAGE_FIELDS)
        .order_by("-id")
    ),
    samples=[("recipient", uuid.UUID(int=0)), ("sender", uuid.UUID(int=1))],
)


def vv_messages_pages_for_user(*, user: User, vv_id: uuid.UUID | str) -> PreparedPages[Message]:
    """The messages the VV received or sent (a message it sent itself once), newest first, as
    a list pages through them: each with its recipient's name (``message.recipient``)."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    return PreparedPages(_MESSAGE_PAGES, (vv.pk, vv.pk))


def vv_storage_get_for_user(*, user: User, vv_id: uuid.UUID | str, key: str) -> StorageDocument:
    """One key of the VV's storage; StorageKeyNotFound when the VV has no such key."""
    try:
        return vv_storage_for_user(user=user, vv_id=vv_id).get(key=key)
    except StorageDocument.DoesNotExist:
        raise StorageKeyNotFound(key) from None


def _task_image_references(vv: VirtualVehicle, containing: str | None = None) -> set[str]:
    # Only the readings of the VV's tasks count: the platform wrote those. A storage value is
    # written by the VV's program and could name any file, another customer's included.
    tasks = Task.objects.filter(vv=vv, status=TaskStatus.DONE, readings__isnull=False)
    if containing is not None:
        # Narrow down in the database first: the file name appears in the readings' JSON text.
        tasks = tasks.annotate(text=Cast("readings", output_field=TextField())).filter(
            text__contains=containing
        )
    references: set[str] = set()
    for readings in tasks.values_list("readings", flat=True).iterator():
        references.update(image_references(readings))
    return references


def vv_image_references_for_user(*, user: User, vv_id: uuid.UUID | str) -> set[str]:
    """Every image reference the VV's readings hold (paths under MEDIA_ROOT)."""
    return _task_image_references(vv_get_for_user(user=user, vv_id=vv_id))


def vv_image_for_user(*, user: User, vv_id: uuid.UUID | str, file: str) -> str:
    """The reference (path under MEDIA_ROOT) of the image named ``file`` that a reading of the
    VV took; ImageNotFound when none of its readings did."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if not IMAGE_FILE.match(file):
        raise ImageNotFound(file)
    for reference in sorted(_task_image_references(vv, containing=file)):
        if image_file(reference) == file:
            return reference
    raise ImageNotFound(file)


# --- the live map ---------------------------------------------------------------------------

# What a map's snapshot holds at most: the VVs that have not ended and those that ended
# recently, and per VV its latest tasks and track points.
MAP_ENDED_VVS = 50
MAP_TASKS_PER_VV = 2_000
MAP_TRACK_PER_VV = 2_000


# VVs whose rows one statement of a snapshot reads at most (SQLite's limit of parameters).
_SNAPSHOT_CHUNK = 500


def _vv_of(row: Any) -> Any:
    return row[0] if isinstance(row, tuple) else row.vv_id


def _by_vv(rows: QuerySet[Any], ids: Sequence[Any]) -> dict[Any, list[Any]]:
    """The rows of these VVs, by VV, in the query's order: one statement per chunk of VVs."""
    found: dict[Any, list[Any]] = {}
    for start in range(0, len(ids), _SNAPSHOT_CHUNK):
        for row in rows.filter(vv_id__in=ids[start : start + _SNAPSHOT_CHUNK]):
            found.setdefault(_vv_of(row), []).append(row)
    return found


def _latest_per_vv(
    rows: QuerySet[Any],
    ids: Sequence[Any],
    order: tuple[str, ...],
    limit: int,
    *,
    fields: tuple[str, ...] = (),
) -> dict[Any, list[Any]]:
    """The last ``limit`` rows of each of these VVs by ``order``, oldest first, by VV (only
    ``fields``, the VV's id first, when given): a window over each VV's rows, for all of them
    at once."""
    latest = rows.annotate(
        rank=Window(
            RowNumber(),
            partition_by=[F("vv_id")],
            order_by=[F(name).desc() for name in order],
        )
    ).filter(rank__lte=limit)
    if fields:
        latest = latest.values_list(*fields)
    return _by_vv(latest.order_by("vv_id", *order), ids)


def map_snapshot_for_user(*, user: User, vv_id: uuid.UUID | str | None = None) -> dict[str, Any]:
    """The live map's state as this user may see it, from the database: operation areas,
    ground stations, and VVs with their tasks, migrations and tracks (the vehicles' live
    positions come from the feed). A customer sees only its own VVs and neither a vehicle's
    nor a ground station's name; ``vv_id`` narrows it to one VV (VVNotFound for another
    customer's). Shapes as in missions/events.py."""
    staff = bool(user.is_staff)
    customer_id = user.customer_id
    vvs = vv_list_for_user(user=user).select_related("host_rv", "host_gs")
    if vv_id is not None:
        chosen = [vv_get_for_user(user=user, vv_id=vv_id)]
    else:
        running = list(vvs.exclude(status__in=ENDED_STATUSES).order_by("submitted_s", "id"))
        ended = list(vvs.filter(status__in=ENDED_STATUSES).order_by("-updated")[:MAP_ENDED_VVS])
        chosen = running + ended

    def shown(event: dict[str, Any]) -> dict[str, Any] | None:
        return event_for(event, customer_id=customer_id, staff=staff)

    ids = [vv.pk for vv in chosen]
    tasks = _latest_per_vv(Task.objects.all(), ids, ("q", "index"), MAP_TASKS_PER_VV)
    track = _latest_per_vv(
        TrackPoint.objects.all(),
        ids,
        ("t_s", "id"),
        MAP_TRACK_PER_VV,
        fields=("vv_id", "t_s", "lat", "lng"),
    )
    migrations = _by_vv(Migration.objects.order_by("vv_id", "at_s", "id"), ids)
    listed = []
    for vv in chosen:
        listed.append(
            shown(vv_event(vv))
            | {
                "tasks": [shown(task_event(t, vv.customer_id)) for t in tasks.get(vv.pk, ())],
                "migrations": [
                    shown(migration_event(m, vv.customer_id)) for m in migrations.get(vv.pk, ())
                ],
                "track": [[t, lat, lng] for _, t, lat, lng in track.get(vv.pk, ())],
            }
        )
    areas = Vehicle.objects.exclude(status=VehicleStatus.REMOVED).order_by("name")
    return {
        "staff": staff,
        "areas": [
            {"name": v.name, "status": v.status, "area": v.area} if staff else {"area": v.area}
            for v in areas
        ],
        "stations": [
            {"name": gs.name, "lat": gs.lat, "lng": gs.lng}
            if staff
            else {"lat": gs.lat, "lng": gs.lng}
            for gs in GroundStation.objects.order_by("name")
        ],
        "vvs": listed,
    }


def flight_tasks(*, flight: Any) -> list[Task]:
    """The tasks an RV served on a flight (staff data): done by it between its take-off and
    its landing (now, while it flies), in the order they were done, with their VV and its
    customer; each with ``done_at``, the date it was done (the flight's clock)."""
    until_s = flight.ended_s if flight.ended_s is not None else float("inf")
    tasks = list(
        Task.objects.filter(
            vehicle_id=flight.vehicle_id,
            status=TaskStatus.DONE,
            done_s__gte=flight.started_s,
            done_s__lte=until_s,
        )
        .select_related("vv__customer")
        .order_by("done_s", "pk")
    )
    for task in tasks:
        task.done_at = flight.started + dt.timedelta(seconds=task.done_s - flight.started_s)  # type: ignore[attr-defined]
    return tasks
