"""The fleet's rows in the store, as the task path reads and writes them: RVs' statuses and
rows, their open tasks (in a planner's order or with their customers' weights), tasks put on
an RV's list, what a control loop reports of its vehicle (its take-offs with their pilot in
command), and the track points of the VVs aboard."""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from django.contrib.auth import get_user_model
from django.db import connection, transaction
from django.db.models import BooleanField, ExpressionWrapper, Q, QuerySet

from cpcc_site.prepared import Many, PreparedRead, deferred, update_row, update_row_with
from fleet.geo import Position
from fleet.models import GroundStation, TakeOff, Vehicle, VehicleStatus
from missions.models import ACTIVE_STATUSES, Task, TaskStatus, TrackPoint, VirtualVehicle
from vvm_worker.services.store.units import db_time_ago

# A list of RV keys in a compiled read: compiled once for each length of list.
_RV_KEYS = Many(lambda i: -7_000_000 - i)

# The statuses of some RVs.
_STATUSES = PreparedRead(
    lambda vehicle_ids: Vehicle.objects.filter(pk__in=vehicle_ids).values_list("pk", "status"),
    samples=[("pk", _RV_KEYS)],
)


def vehicle_statuses(vehicle_ids: Sequence[int]) -> list[tuple[int, str]]:
    """(RV, status) of these RVs."""
    return _STATUSES.rows(vehicle_ids)


def vehicle_statuses_later(vehicle_ids: Sequence[int]) -> Callable[[], list[tuple[int, str]]]:
    """``vehicle_statuses``, sent now and read by the function it gives back (in a pipelined
    unit of work, with what is sent in between)."""
    return _STATUSES.rows_later(vehicle_ids)


@functools.cache
def _vehicles_read(lease_s: float | None) -> PreparedRead[Vehicle]:
    def build(ids: list[int]) -> QuerySet[Vehicle]:
        vehicles = Vehicle.objects.filter(pk__in=ids).exclude(status=VehicleStatus.REMOVED)
        if lease_s is None:
            return vehicles
        online = Q(worker_seen__gte=db_time_ago(lease_s))
        return vehicles.annotate(online=ExpressionWrapper(online, output_field=BooleanField()))

    return PreparedRead(build, samples=[("pk", _RV_KEYS)])


def vehicles_in_fleet(vehicle_ids: Sequence[int], *, lease_s: float | None) -> list[Vehicle]:
    """The rows of these RVs that are not removed; with ``lease_s``, each with ``online``:
    whether its worker renewed its lease within lease_s, by the database's clock."""
    return _vehicles_read(lease_s).all(vehicle_ids)


# The open tasks of some RVs, oldest first.
_ROUTES = PreparedRead(
    lambda vehicle_ids: (
        Task.objects.filter(status=TaskStatus.OPEN, vehicle_id__in=vehicle_ids)
        .order_by("requested_s", "id")
        .values_list("pk", "vehicle_id", "lat", "lng", "alt", "vv__customer__service_class_id")
    ),
    samples=[("vehicle", _RV_KEYS)],
)


def open_tasks_of_vehicles(
    vehicle_ids: Sequence[int],
) -> list[tuple[int, int, float, float, float, int | None]]:
    """(task, RV, lat, lng, alt, service class) of the open tasks on these RVs' lists, oldest
    first (the class of the task's VV's customer; None: none)."""
    return _ROUTES.rows(vehicle_ids) if vehicle_ids else []


# The columns of ``vehicle_tasks``' rows, in order; the last three are the task's customer's
# service class weight, target and id (None: no class).
VEHICLE_TASK_COLUMNS = (
    "id",
    "lat",
    "lng",
    "alt",
    "tolerance_m",
    "requested_s",
    "sensors",
    "vv_id",
    "q",
    "vv__customer__service_class__weight",
    "vv__customer__service_class__p95_s",
    "vv__customer__service_class_id",
)
_VEHICLE_TASKS = PreparedRead(
    lambda vehicle_id: (
        Task.objects.filter(vehicle_id=vehicle_id, status=TaskStatus.OPEN)
        .order_by("requested_s", "id")
        .values_list(*VEHICLE_TASK_COLUMNS)
    ),
    samples=[("vehicle", -7_654_321)],
)


def vehicle_tasks(vehicle_id: int) -> list[tuple[Any, ...]]:
    """The open tasks on the RV's list, oldest request first, as ``VEHICLE_TASK_COLUMNS``."""
    return _VEHICLE_TASKS.rows(vehicle_id)


# The VV's hosts (read right after the commit that moved it).
_HOSTS = PreparedRead(
    lambda vv_id: VirtualVehicle.objects.filter(pk=vv_id).values_list("host_gs_id", "host_rv_id"),
    samples=[("pk", uuid.UUID(int=0))],
)


def vv_hosts(vv_id: uuid.UUID) -> tuple[int | None, int | None] | None:
    """(ground station, RV) the VV is on; None when there is no such VV."""
    rows = _HOSTS.rows(vv_id)
    return rows[0] if rows else None


# Every ground station (read for every VV that ends on an RV).
_STATIONS = PreparedRead(lambda: GroundStation.objects.all(), samples=[])


def ground_stations() -> list[GroundStation]:
    """Every ground station."""
    return _STATIONS.all()


def tasks_assigned(task_ids: Sequence[int], *, vehicle_id: int, now: float) -> None:
    """These tasks are on the RV's list since ``now``: written without waiting (nothing in
    the unit of work reads them back)."""
    with deferred():
        for task_id in task_ids:
            update_row(Task, task_id, values={"vehicle": vehicle_id, "assigned_s": now})


def vehicle_report(
    vehicle_id: int,
    *,
    values: dict[str, Any],
    add: dict[str, int] | None,
    track_point: tuple[float, Position] | None = None,
    take_offs: Sequence[tuple[float, dt.datetime]] = (),
) -> None:
    """The RV's row: ``values`` set, ``add`` added to its counters; with ``track_point``
    (time, position), that point on the track of every VV aboard now, found by the database
    in the same commit (on PostgreSQL, the same statement); ``take_offs`` (platform clock,
    date) recorded in the same commit (``take_offs_insert``). Inside the caller's transaction
    when there is one."""
    if track_point is None and not take_offs:
        with deferred():
            update_row(Vehicle, vehicle_id, values=values, add=add)
        return
    # One commit for the track points, the take-offs and the row (a lone UPDATE commits by
    # itself).
    alone = connection.get_autocommit()
    with transaction.atomic() if alone else contextlib.nullcontext(), deferred():
        take_offs_insert(vehicle_id, take_offs)
        if track_point is None:
            update_row(Vehicle, vehicle_id, values=values, add=add)
            return
        track = _track_points_statement(vehicle_id, [track_point])
        update_row_with(Vehicle, vehicle_id, values=values, add=add, write=track)


def take_offs_insert(vehicle_id: int, take_offs: Sequence[tuple[float, dt.datetime]]) -> None:
    """The RV's take-offs (platform clock, date), each with the pilot on duty for it as the
    database has it now: one INSERT ... SELECT from the RV's row (its pilot's name joined),
    no read of its own; sent without waiting in a pipelined unit of work."""
    if not take_offs:
        return
    users = get_user_model()
    username = users._meta.get_field(users.USERNAME_FIELD).column
    adapt = connection.ops.adapt_datetimefield_value
    rows = " UNION ALL ".join(['SELECT %s AS "at", %s AS "at_s"'] * len(take_offs))
    sql = (
        f'INSERT INTO "{TakeOff._meta.db_table}" '
        '("vehicle_id", "at", "at_s", "pilot_id", "pilot_name") '
        f'SELECT v."id", p."at", p."at_s", v."pilot_on_duty_id", COALESCE(u."{username}", \'\') '
        f'FROM ({rows}) p CROSS JOIN "{Vehicle._meta.db_table}" v '
        f'LEFT JOIN "{users._meta.db_table}" u ON u."id" = v."pilot_on_duty_id" '
        'WHERE v."id" = %s'
    )
    params = [value for at_s, at in take_offs for value in (adapt(at), at_s)]
    with deferred(), connection.cursor() as cursor:
        cursor.execute(sql, [*params, vehicle_id])


def track_points_aboard(vehicle_id: int, points: Sequence[tuple[float, Position]]) -> None:
    """Track points (time, position) for every VV aboard the RV now: one INSERT ... SELECT."""
    sql, params = _track_points_statement(vehicle_id, points)
    with connection.cursor() as cursor:
        cursor.execute(sql, params)


def _track_points_statement(
    vehicle_id: int, points: Sequence[tuple[float, Position]]
) -> tuple[str, list[Any]]:
    """``track_points_aboard``'s statement and its parameters."""
    track, vvs = TrackPoint._meta.db_table, VirtualVehicle._meta.db_table
    statuses = [str(status) for status in ACTIVE_STATUSES]
    marks = ", ".join(["%s"] * len(statuses))
    rows = " UNION ALL ".join(
        ['SELECT %s AS "t_s", %s AS "lat", %s AS "lng", %s AS "alt"'] * len(points)
    )
    values = [v for t_s, p in points for v in (t_s, p.lat, p.lng, p.alt)]
    return (
        f'INSERT INTO "{track}" ("vv_id", "t_s", "lat", "lng", "alt") '
        f'SELECT v."id", p."t_s", p."lat", p."lng", p."alt" FROM "{vvs}" v, ({rows}) p '
        f'WHERE v."host_rv_id" = %s AND v."status" IN ({marks}) '
        'ORDER BY p."t_s", v."submitted_s", v."id"',
        [*values, vehicle_id, *statuses],
    )
