"""The fleet's rows in the store, as the task path reads and writes them: RVs' statuses and
rows, their open tasks (in a planner's order or with their customers' weights), tasks put on
an RV's list, what a control loop reports of its vehicle (its take-offs with their pilot in
command), and the track points of the VVs aboard."""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import json
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from django.contrib.auth import get_user_model
from django.db import connection, transaction
from django.db.models import BooleanField, ExpressionWrapper, Q, QuerySet

from accounts.models import Customer
from cpcc_site.prepared import Many, PreparedRead, deferred, update_row, update_row_with
from fleet.geo import Position
from fleet.models import Flight, GroundStation, Vehicle, VehicleStatus
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
    take_offs: Sequence[TakeOffRow] = (),
    landings: Sequence[LandingRow] = (),
) -> None:
    """The RV's row: ``values`` set, ``add`` added to its counters; with ``track_point``
    (time, position), that point on the track of every VV aboard now, found by the database
    in the same commit (on PostgreSQL, the same statement); ``take_offs`` and ``landings``
    recorded in the same commit (``flights_write``). Inside the caller's transaction when
    there is one."""
    if track_point is None and not take_offs and not landings:
        with deferred():
            update_row(Vehicle, vehicle_id, values=values, add=add)
        return
    # One commit for the track points, the flights and the row (a lone UPDATE commits by
    # itself).
    alone = connection.get_autocommit()
    with transaction.atomic() if alone else contextlib.nullcontext(), deferred():
        flights_write(vehicle_id, take_offs=take_offs, landings=landings)
        if track_point is None:
            update_row(Vehicle, vehicle_id, values=values, add=add)
            return
        track = _track_points_statement(vehicle_id, [track_point])
        update_row_with(Vehicle, vehicle_id, values=values, add=add, write=track)


@dataclass(frozen=True)
class TakeOffRow:
    """A take-off as the flights' rows take it: when (platform clock, date) and the RV's
    odometers then (metres, seconds flown)."""

    t_s: float
    at: dt.datetime
    distance_m: float
    flight_s: float


@dataclass(frozen=True)
class LandingRow:
    """The end of the flight that took off at ``took_off_s`` (platform clock): when
    (platform clock, date), how (``FlightEnd``'s value), the RV's odometers then, the highest
    altitude above its depot, the battery in percent at the take-off and at the end, and its
    track: [t_s, lat, lng, alt, battery_pct or None] at each report of the loop in flight."""

    took_off_s: float
    t_s: float
    at: dt.datetime
    how: str
    distance_m: float
    flight_s: float
    max_alt_m: float | None
    battery_start_pct: float | None
    battery_end_pct: float | None
    track: Sequence[Sequence[float | None]] = ()


def flights_write(
    vehicle_id: int, *, take_offs: Sequence[TakeOffRow] = (), landings: Sequence[LandingRow] = ()
) -> None:
    """The RV's flights: the take-offs first (``take_offs_insert``: each opens one), then the
    landings (``landing_update``: each closes the flight of its take-off, which may be one of
    these). Sent without waiting in a pipelined unit of work."""
    take_offs_insert(vehicle_id, take_offs)
    for landing in landings:
        landing_update(vehicle_id, landing)


def take_offs_insert(vehicle_id: int, take_offs: Sequence[TakeOffRow]) -> None:
    """The RV's take-offs: a Flight each, open, with the pilot on duty for it as the database
    has it now and the RV's odometers at the take-off (as its loop reported them: the row may
    be behind): one INSERT ... SELECT from the RV's row (its pilot's name joined), no read of
    its own; sent without waiting in a pipelined unit of work."""
    if not take_offs:
        return
    users = get_user_model()
    username = users._meta.get_field(users.USERNAME_FIELD).column
    adapt = connection.ops.adapt_datetimefield_value
    rows = " UNION ALL ".join(
        ['SELECT %s AS "at", %s AS "at_s", %s AS "odometer_m", %s AS "flight_s"'] * len(take_offs)
    )
    sql = (
        f'INSERT INTO "{Flight._meta.db_table}" '
        '("vehicle_id", "started", "started_s", "pilot_id", "pilot_name", "odometer_start_m", '
        '"flight_s_start", "ended_how", "battery_name", "tasks_served", "customers", "vvs", '
        '"track", "log") '
        f'SELECT v."id", p."at", p."at_s", v."pilot_on_duty_id", COALESCE(u."{username}", \'\'), '
        "p.\"odometer_m\", p.\"flight_s\", '', '', 0, '[]', '[]', '[]', '' "
        f'FROM ({rows}) p CROSS JOIN "{Vehicle._meta.db_table}" v '
        f'LEFT JOIN "{users._meta.db_table}" u ON u."id" = v."pilot_on_duty_id" '
        'WHERE v."id" = %s'
    )
    params = [
        value
        for t in take_offs
        for value in (adapt(t.at), t.t_s, float(t.distance_m), float(t.flight_s))
    ]
    with deferred(), connection.cursor() as cursor:
        cursor.execute(sql, [*params, vehicle_id])


def landing_update(vehicle_id: int, landing: LandingRow) -> None:
    """Close the RV's flight that took off at ``landing.took_off_s`` (none open: nothing): its
    end, how, duration and distance (what the RV's odometers gained since the take-off: the
    seconds it flew, as its driver counts them, and the metres), highest altitude and
    battery, and what it served meanwhile, found by the database in the same statement: the
    tasks the RV answered done between the take-off and the end, their customers and their
    VVs ([{id, name}], by name). One UPDATE, sent without waiting in a pipelined unit of
    work."""
    sql = _landing_sql(connection.vendor)
    served = [vehicle_id, TaskStatus.DONE.value, landing.took_off_s, landing.t_s]
    params = [
        connection.ops.adapt_datetimefield_value(landing.at),
        landing.t_s,
        landing.how,
        float(landing.flight_s),
        float(landing.distance_m),
        landing.max_alt_m,
        landing.battery_start_pct,
        landing.battery_end_pct,
        json.dumps([list(point) for point in landing.track]),
        *served,
        *served,
        *served,
        vehicle_id,
        landing.took_off_s,
    ]
    with deferred(), connection.cursor() as cursor:
        cursor.execute(sql, params)


@functools.cache
def _landing_sql(vendor: str) -> str:
    """``landing_update``'s statement for the database ``vendor`` (its JSON functions)."""
    tasks, vvs = Task._meta.db_table, VirtualVehicle._meta.db_table
    customers = Customer._meta.db_table
    where = 'WHERE t."vehicle_id" = %s AND t."status" = %s AND t."done_s" BETWEEN %s AND %s'
    served = f'FROM "{tasks}" t JOIN "{vvs}" w ON w."id" = t."vv_id" {where}'
    of_customers = (
        f'FROM "{tasks}" t JOIN "{vvs}" w ON w."id" = t."vv_id" '
        f'JOIN "{customers}" c ON c."id" = w."customer_id" {where}'
    )
    as_json = "CAST(%s AS jsonb)" if vendor == "postgresql" else "%s"
    if vendor == "postgresql":
        vv_id = 'CAST(w."id" AS text)'

        def agg(key: str, name: str) -> str:
            return (
                f"COALESCE(jsonb_agg(jsonb_build_object('id', x.{key}, 'name', x.{name}) "
                f"ORDER BY x.{name}, x.{key}), '[]'::jsonb)"
            )
    else:  # SQLite: a UUID is kept as 32 hex digits; written as Django writes it
        vv_id = (
            "substr(w.\"id\", 1, 8) || '-' || substr(w.\"id\", 9, 4) || '-' || "
            "substr(w.\"id\", 13, 4) || '-' || substr(w.\"id\", 17, 4) || '-' || "
            'substr(w."id", 21, 12)'
        )

        def agg(key: str, name: str) -> str:
            return f"COALESCE(json_group_array(json_object('id', x.{key}, 'name', x.{name})), '[]')"

    return (
        f'UPDATE "{Flight._meta.db_table}" SET "ended" = %s, "ended_s" = %s, "ended_how" = %s, '
        '"duration_s" = %s - "flight_s_start", "distance_m" = %s - "odometer_start_m", '
        '"max_alt_m" = %s, "battery_start_pct" = %s, "battery_end_pct" = %s, '
        f'"track" = {as_json}, '
        f'"tasks_served" = (SELECT COUNT(*) {served}), '
        f'"customers" = (SELECT {agg("cid", "cname")} FROM (SELECT DISTINCT c."id" AS cid, '
        f'c."name" AS cname {of_customers} ORDER BY cname, cid) x), '
        f'"vvs" = (SELECT {agg("vid", "vname")} FROM (SELECT DISTINCT {vv_id} AS vid, '
        f'w."name" AS vname {served} ORDER BY vname, vid) x) '
        'WHERE "vehicle_id" = %s AND "started_s" = %s AND "ended_s" IS NULL'
    )


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
