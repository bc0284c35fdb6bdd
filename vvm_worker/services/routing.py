"""The vehicle mapper and the migrator: who serves a VV's pending task, and moving the VV there."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import itertools
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from django.conf import settings
from django.db.models import Count, Max, QuerySet
from django.db.models.signals import m2m_changed, post_delete, post_save
from shapely import STRtree
from shapely.geometry import Point

from fleet.airspace import Airspace
from fleet.geo import Position
from fleet.models import GroundStation, NoFlyZone, Vehicle, VehicleStatus
from missions.events import migration_event, task_event
from missions.models import (
    HostKind,
    JournalEntry,
    Migration,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from vvm_worker.dispatch import HostRef
from vvm_worker.level_figures import ClassTerms
from vvm_worker.mapping import (
    NO_RESERVE,
    ExclusionZone,
    MapDecision,
    Reserve,
    VehicleCaps,
    map_task,
)
from vvm_worker.runtime import (
    PendingRequest,
    TaskRequest,
    answer_reject,
)
from vvm_worker.services.base import (
    VVM,
    LocalRV,
    customer_named,
    ground_station_for,
    logger,
    pending_of,
)
from vvm_worker.services.journal import journal_append
from vvm_worker.services.service_levels import classes_giving_way
from vvm_worker.services.store import (
    db_time_ago,
    open_tasks_of_vehicles,
    request_tasks_of,
    rows_add,
    tasks_assigned,
    vehicle_statuses,
    vehicle_statuses_later,
    vehicles_in_fleet,
)
from vvm_worker.services.waiting import vv_wait_end, vv_wait_start


def takes_work(vehicle: Vehicle, *, require_pilot: bool) -> bool:
    """Whether routing gives the RV new work: it is in service and, where a pilot is
    required (``require_pilot``: CPCC_REQUIRE_PILOT, read once by the caller), a pilot is on
    duty for it. (Its worker being online is the caller's to add.)"""
    return vehicle.status == VehicleStatus.ACTIVE and (
        not require_pilot or vehicle.pilot_on_duty_id is not None
    )


def vehicle_caps(
    vehicle: Vehicle, open_tasks: int = 0, route: tuple[Position, ...] = ()
) -> VehicleCaps:
    """The mapper's view of one RV (active: it takes new work, ``takes_work``)."""
    return VehicleCaps(
        id=vehicle.pk,
        name=vehicle.name,
        area=vehicle.area_polygon,
        min_altitude_m=vehicle.min_altitude_m,
        max_altitude_m=vehicle.max_altitude_m,
        sensors=_sensor_names(vehicle),
        active=takes_work(vehicle, require_pilot=settings.CPCC_REQUIRE_PILOT),
        position=vehicle.position,
        max_speed_mps=vehicle.max_speed_mps,
        climb_rate_mps=vehicle.climb_rate_mps,
        open_tasks=open_tasks,
        route=route,
        kind=vehicle.kind,
        dive_rate_mps=vehicle.dive_rate_mps,
    )


def no_fly_zones() -> tuple[ExclusionZone, ...]:
    """The provider's no-fly zones as the mapper checks them."""
    return tuple(
        ExclusionZone(z.area_polygon, z.min_altitude_m, z.max_altitude_m)
        for z in NoFlyZone.objects.all()
    )


def _sensor_names(vehicle: Vehicle) -> frozenset[str]:
    # From the prefetched sensors when the caller prefetched them, else one query.
    return frozenset(s.name for s in vehicle.sensors.all())


@dataclasses.dataclass(frozen=True)
class _FleetShape:
    """The part of the mapper's view that changes only when the provider changes an RV (a new
    version of the fleet's rows): each RV in service or maintenance with its area, altitudes,
    sensors and speeds, a spatial index of the areas, and which areas overlap."""

    caps: dict[int, VehicleCaps]  # in name order; live fields are filled in per call
    rows: dict[int, Vehicle]  # the rows the shape was made of (live fields as they were then)
    ids: tuple[int, ...]  # in the order of the index's geometries
    index: STRtree
    overlaps: dict[int, frozenset[int]]
    airspace: Airspace  # the provider's no-fly zones, with the ways around them

    def covering(self, requests: Iterable[TaskRequest]) -> set[int]:
        """The RVs whose areas hold any of the requests' points (border included)."""
        found: set[int] = set()
        for r in requests:
            found.update(self.ids[i] for i in self.index.query(Point(r.lng, r.lat)))
        return found


_shapes_seen: dict[tuple[Any, ...], _FleetShape] = {}
# The airspace of the zones last read, by their version: a new shape of the same zones keeps
# it (and every way it has found).
_airspace_seen: tuple[tuple[Any, ...], Airspace] | None = None
# A vehicle row changed in this process (saved, deleted, its sensors): the version is read
# again at once. A change made by another process is seen within SHAPE_LOOK_S (the version
# is read at most that often otherwise); the RV's own host hears of it by message anyway.
SHAPE_LOOK_S = 1.0
_shape_generation = itertools.count()
_shape_seen_at: tuple[int, float, _FleetShape] | None = None  # (generation, monotonic, shape)
_generation = 0


def _vehicles_changed(**kwargs: Any) -> None:
    global _generation
    _generation = next(_shape_generation) + 1


post_save.connect(_vehicles_changed, sender=Vehicle, dispatch_uid="cpcc-fleet-shape-save")
post_save.connect(_vehicles_changed, sender=NoFlyZone, dispatch_uid="cpcc-fleet-shape-zone")
post_delete.connect(
    _vehicles_changed, sender=NoFlyZone, dispatch_uid="cpcc-fleet-shape-zone-delete"
)
post_delete.connect(_vehicles_changed, sender=Vehicle, dispatch_uid="cpcc-fleet-shape-delete")
m2m_changed.connect(
    _vehicles_changed, sender=Vehicle.sensors.through, dispatch_uid="cpcc-fleet-shape-sensors"
)


def _fleet_shape() -> _FleetShape:
    """The fleet's shape, read again only when a vehicle row changed: one light query, at
    most every SHAPE_LOOK_S unless this process changed a vehicle."""
    global _shape_seen_at, _airspace_seen
    seen = _shape_seen_at
    now = time.monotonic()
    if seen is not None and seen[0] == _generation and now - seen[1] < SHAPE_LOOK_S:
        return seen[2]
    generation = _generation
    version = Vehicle.objects.aggregate(count=Count("id"), changed=Max("updated"), top=Max("id"))
    zoned = NoFlyZone.objects.aggregate(count=Count("id"), changed=Max("updated"))
    key = (version["count"], version["changed"], version["top"], zoned["count"], zoned["changed"])
    shape = _shapes_seen.get(key)
    if shape is None:
        vehicles = list(
            Vehicle.objects.exclude(status=VehicleStatus.REMOVED).prefetch_related("sensors")
        )
        zones = no_fly_zones()
        zones_key = (zoned["count"], zoned["changed"])
        if _airspace_seen is None or _airspace_seen[0] != zones_key:
            _airspace_seen = (zones_key, Airspace(zones))
        airspace = _airspace_seen[1]
        # The live fields come with each call; a vehicle that never flew is at its depot.
        caps = {
            v.pk: dataclasses.replace(vehicle_caps(v), position=v.depot, no_fly=zones)
            for v in vehicles
        }
        ids = tuple(caps)
        areas = [caps[i].area for i in ids]
        index = STRtree(areas)
        overlaps = {}
        for k, a in enumerate(ids):
            near = (ids[j] for j in index.query(areas[k]) if ids[j] != a)
            overlaps[a] = frozenset(
                b for b in near if caps[a].area.intersection(caps[b].area).area > 0.0
            )
        shape = _FleetShape(caps, {v.pk: v for v in vehicles}, ids, index, overlaps, airspace)
        _shapes_seen.clear()
        _shapes_seen[key] = shape
    _shape_seen_at = (generation, now, shape)
    return shape


def fleet_airspace() -> Airspace:
    """The provider's no-fly zones as the vehicles fly around them (the same object while the
    zones do not change)."""
    return _fleet_shape().airspace


def fleet_caps(
    vvm: VVM, requests: Sequence[TaskRequest] | None = None, shape: _FleetShape | None = None
) -> list[VehicleCaps]:
    """The mapper's view of the fleet: every RV that is in service or in maintenance; one whose
    worker is gone counts as in maintenance (it may come back), and so does one with no pilot
    on duty where CPCC_REQUIRE_PILOT requires one. With ``requests``, only the RVs whose areas
    hold one of them: no other could serve them (`map_task` decides the same)."""
    return fleet_caps_and_rows(vvm, requests, shape)[0]


def fleet_caps_and_rows(
    vvm: VVM, requests: Sequence[TaskRequest] | None = None, shape: _FleetShape | None = None
) -> tuple[list[VehicleCaps], dict[int, Vehicle]]:
    """``fleet_caps`` and the rows of those RVs as read for it (by id): one read of the RVs,
    one of their open tasks (none when ``requests`` leave one RV to choose: its caps then
    say nothing of its open tasks)."""
    view = _fleet_view(vvm, requests, shape, require_pilot=settings.CPCC_REQUIRE_PILOT)
    return view.caps, view.rows


@dataclasses.dataclass(frozen=True)
class _FleetView:
    """``fleet_caps_and_rows``' answer, and the RVs among them that are in service with their
    worker online but count as out of it for want of a pilot on duty (``pilotless``)."""

    caps: list[VehicleCaps]
    rows: dict[int, Vehicle]
    pilotless: frozenset[int] = frozenset()


def _fleet_view(
    vvm: VVM,
    requests: Sequence[TaskRequest] | None,
    shape: _FleetShape | None,
    *,
    require_pilot: bool,
) -> _FleetView:
    """``fleet_caps_and_rows``, with ``require_pilot`` (CPCC_REQUIRE_PILOT, read once by the
    caller): an RV with no pilot on duty is not active then. (The rows carry their pilot on
    duty: no read of its own.)"""
    shape = shape or _fleet_shape()
    wanted = shape.covering(requests) if requests is not None else set(shape.ids)
    if not wanted:
        return _FleetView([], {})
    # An RV's open tasks, in its plan's order, rank it against the others: with one RV to
    # choose (the common case where areas do not overlap), they are not read.
    ranked = requests is None or len(wanted) > 1
    # The RVs this process hosts are asked, the others read.
    local = vvm.local_fleet
    known = {
        pk: live for pk in wanted if local and (live := local.live(pk, route=ranked)) is not None
    }
    found = _rows_hosted_here(vvm, known, shape)
    found.add(_rows_hosted_elsewhere(vvm, sorted(wanted - set(known)), ranked=ranked))
    caps = []
    pilotless = set()
    for pk, static in shape.caps.items():
        vehicle = found.rows.get(pk)
        if vehicle is None:
            continue
        reported = vehicle.lat is not None and vehicle.lng is not None
        route = found.routes.get(pk, ())
        in_service = vehicle.status == VehicleStatus.ACTIVE and found.online[pk]
        if in_service and require_pilot and vehicle.pilot_on_duty_id is None:
            in_service = False
            pilotless.add(pk)
        caps.append(
            dataclasses.replace(
                static,
                active=in_service,
                position=vehicle.position if reported else static.position,
                open_tasks=len(route),
                route=route,
                task_classes=found.classes.get(pk, ()),
            )
        )
    return _FleetView(caps, found.rows, frozenset(pilotless))


@dataclasses.dataclass
class _FleetRows:
    """Some RVs as routing sees them: their rows, their routes and the service classes of
    their open tasks, whether their worker is online (by id)."""

    rows: dict[int, Vehicle] = dataclasses.field(default_factory=dict)
    routes: dict[int, tuple[Position, ...]] = dataclasses.field(default_factory=dict)
    classes: dict[int, tuple[int | None, ...]] = dataclasses.field(default_factory=dict)
    online: dict[int, bool] = dataclasses.field(default_factory=dict)

    def add(self, other: _FleetRows) -> None:
        self.rows.update(other.rows)
        self.routes.update(other.routes)
        self.classes.update(other.classes)
        self.online.update(other.online)


def _rows_hosted_here(vvm: VVM, known: dict[int, LocalRV], shape: _FleetShape) -> _FleetRows:
    """The RVs this process hosts (``known``: what their loops know), their rows as the
    fleet's shape has them with the loops' positions and statuses (a status a loop does not
    know is read: ahead, when the unit of work sent that read); their worker is this process.
    A removed RV is left out."""
    unsure = sorted(pk for pk, live in known.items() if live.status is None)
    statuses = vvm.statuses_ahead() if unsure and vvm.statuses_ahead is not None else {}
    if any(pk not in statuses for pk in unsure):
        statuses = dict(vehicle_statuses(unsure))
    found = _FleetRows()
    for pk, live in known.items():
        status = live.status if live.status is not None else statuses.get(pk)
        if status is None or status == VehicleStatus.REMOVED or pk not in shape.rows:
            continue
        row = copy.copy(shape.rows[pk])
        row._state = copy.copy(row._state)
        row.status = status
        row.lat, row.lng, row.alt = live.position.lat, live.position.lng, live.position.alt
        found.rows[pk], found.routes[pk], found.online[pk] = row, live.route, True
        found.classes[pk] = live.classes
    return found


def _rows_hosted_elsewhere(vvm: VVM, vehicle_ids: list[int], *, ranked: bool) -> _FleetRows:
    """These RVs as read (the removed left out), with their planned routes when ``ranked``,
    online when their worker renewed its lease in time (always, without leases)."""
    found = _FleetRows()
    if not vehicle_ids:
        return found
    found.rows = {v.pk: v for v in vehicles_in_fleet(vehicle_ids, lease_s=vvm.lease_s)}
    if ranked:
        found.routes, found.classes = planned_routes(
            {pk: v.planner_state for pk, v in found.rows.items()}
        )
    found.online = {
        pk: vvm.lease_s is None or bool(getattr(vehicle, "online", False))
        for pk, vehicle in found.rows.items()
    }
    return found


@contextlib.contextmanager
def rv_statuses_read_ahead(*, vvm: VVM) -> Iterator[None]:
    """Inside the block (a unit of work in a worker of several RVs), routing takes the
    statuses of this process's RVs from one read sent now: it goes to the database with the
    statements sent next and its answer comes back with theirs, with no round trip of its
    own. (The statuses are then read when the unit of work starts, in its transaction,
    instead of when it routes the VV: a change committed in between is seen at the next
    routing, as one committed right after it would be.) Elsewhere it changes nothing."""
    if not vvm.local_rvs or vvm.statuses_ahead is not None:
        yield
        return
    read = vehicle_statuses_later(sorted(vvm.local_rvs))
    read_once: dict[int, str] | None = None

    def statuses() -> dict[int, str]:
        nonlocal read_once
        if read_once is None:
            read_once = {pk: str(status) for pk, status in read()}
        return read_once

    vvm.statuses_ahead = statuses
    try:
        yield
        statuses()  # read, so that nothing is left unread when the unit of work ends
    finally:
        vvm.statuses_ahead = None


def planned_routes(
    plans: dict[int, Any],
) -> tuple[dict[int, tuple[Position, ...]], dict[int, tuple[int | None, ...]]]:
    """The open tasks of these RVs (id -> the planner state it saved), in the order its planner
    last meant to serve them (tasks the plan does not know yet come last, oldest first), and
    the service class of each of them (oldest first; None: no class)."""
    rows = open_tasks_of_vehicles(sorted(plans))
    tasks: dict[int, list[tuple[int, Position]]] = {}
    classes: dict[int, list[int | None]] = {}
    for pk, vehicle_id, lat, lng, alt, service_class in rows:
        tasks.setdefault(vehicle_id, []).append((pk, Position(lat, lng, alt)))
        classes.setdefault(vehicle_id, []).append(service_class)
    routes = {
        vehicle_id: planned_order(items, plans[vehicle_id]) for vehicle_id, items in tasks.items()
    }
    return routes, {vehicle_id: tuple(c) for vehicle_id, c in classes.items()}


def planned_order(items: Sequence[tuple[int, Position]], state: Any) -> tuple[Position, ...]:
    """An RV's open tasks (id, position), oldest first, in the order of its planner's state
    (tasks the plan does not know yet come last, oldest first)."""
    plan = state.get("route", []) if isinstance(state, dict) else []
    rank = {task_id: k for k, task_id in enumerate(plan if isinstance(plan, list) else [])}
    ordered = sorted(items, key=lambda item: rank.get(item[0], len(rank)))
    return tuple(position for _, position in ordered)


def online_vehicles(vvm: VVM) -> QuerySet[Vehicle]:
    """RVs whose worker renewed its lease within ``lease_s``, by the database's clock (the
    one ``vehicle_heartbeat`` writes with), whatever the clocks of the workers say."""
    assert vvm.lease_s is not None
    return Vehicle.objects.filter(worker_seen__gte=db_time_ago(vvm.lease_s))


def vv_route(*, vv: VirtualVehicle, vvm: VVM, open_tasks: Sequence[Task] | None = None) -> bool:
    """Find who serves the pending request. True when the VV must step again right here.

    ``open_tasks``: the request's open tasks as the caller has them, in index order (new
    ones not saved yet: they are saved assigned, or rejected, by the caller); None: read them.
    The caller saves the VV.

    A VV parked on a ground station because only RVs out of service (or, with
    CPCC_REQUIRE_PILOT, in service with no pilot on duty) could serve its next task waits
    (``vv_wait_start``: its owner reads why); one that waited and moves on stops waiting
    (``vv_wait_end``). Neither writes anything for a VV that did not wait and does not (the
    common case)."""
    waited = bool(vv.waiting_reason)
    again, parked = _route(vv, vvm, open_tasks)
    if parked is not None:
        vv_wait_start(vv=vv, task=parked.task, vvm=vvm, no_pilot=parked.no_pilot)
    elif waited:
        vv_wait_end(vv=vv, vvm=vvm)
    return again


@dataclasses.dataclass(frozen=True)
class _Parked:
    """The task a parked VV waits for, and whether a pilot coming on duty would do
    (``no_pilot``: an RV that serves it is in service, with no pilot on duty)."""

    task: Task
    no_pilot: bool = False


def _route(
    vv: VirtualVehicle, vvm: VVM, open_tasks: Sequence[Task] | None
) -> tuple[bool, _Parked | None]:
    """``vv_route``'s decision: whether the VV must step again, and what it waits for when it
    is parked until an RV that serves it is in service again (else None)."""
    pending = pending_of(vv)
    assert pending is not None
    if open_tasks is None:
        open_tasks = request_tasks_of(vv.pk, pending.q)
    require_pilot = settings.CPCC_REQUIRE_PILOT
    shape = _fleet_shape()
    stays, mine = _stays_aboard_alone(vv, open_tasks, shape, vvm, require_pilot=require_pilot)
    if stays:
        return False, None
    requests = [request_of(t) for t in open_tasks]
    view = _fleet_view(vvm, requests, shape, require_pilot=require_pilot)
    fleet, rows = view.caps, view.rows
    due = _due_in(vv, vvm)
    service_class = vv.customer.service_class_id
    # Where more than one RV is to choose from, the classes with slack leave a reserve.
    reserve = NO_RESERVE
    if sum(1 for caps in fleet if caps.active) > 1:
        reserve = Reserve(classes_giving_way(now_s=vvm.clock.now_s(), vvm=vvm))
    decisions = [
        map_task(r, fleet, due_in_s=due(t), service_class=service_class, reserve=reserve)
        for t, r in zip(open_tasks, requests, strict=True)
    ]
    host = vv.host_rv
    if host is not None and mine and _stays(host, open_tasks, mine, fleet, decisions, due):
        tasks_assign(tasks=mine, vehicle=host, vvm=vvm)
        return False, None
    rejected = [(t, d) for t, d in zip(open_tasks, decisions, strict=True) if d.rejected]
    # A batch is accepted or rejected as a whole, before any of its tasks is answered.
    if rejected and not _partly_answered(vv, pending):
        if vv.host_rv is not None:
            vv_migrate_to_ground_station(
                vv=vv, reason="no vehicle can serve its task", vvm=vvm, open_tasks=open_tasks
            )
            return False, None
        vv_reject_request(vv=vv, pending=pending, rejected=rejected, open_tasks=open_tasks, vvm=vvm)
        return True, None
    best = _best_vehicle(open_tasks, decisions)
    if best is not None:
        _move_to(vv, rows[best.id], _servable(best, open_tasks), open_tasks, vvm)
        return False, None
    # Only RVs in maintenance (or with no pilot on duty) could serve it: park on a ground
    # station until one returns.
    if vv.host_rv is not None:
        vv_migrate_to_ground_station(
            vv=vv, reason="waiting for a vehicle", vvm=vvm, open_tasks=open_tasks
        )
    k = next((k for k, d in enumerate(decisions) if d.parked), None)
    if k is None:
        return False, None
    # A pilot would do where an RV in service that serves it lacks one (one in maintenance
    # besides may come back too, but the pilot is what the owner can be told to wait for).
    no_pilot = any(c.id in view.pilotless and c.can_serve(requests[k]) for c in fleet)
    return False, _Parked(open_tasks[k], no_pilot=no_pilot)


def _stays_aboard_alone(
    vv: VirtualVehicle,
    open_tasks: Sequence[Task],
    shape: _FleetShape,
    vvm: VVM,
    *,
    require_pilot: bool,
) -> tuple[bool, list[Task]]:
    """The common case, which needs no look at the rest of the fleet: the RV aboard takes
    work (in service; with ``require_pilot``, a pilot on duty) and can serve the tasks
    (``mine``: those it can), and no other RV's area overlaps its own, so they go on its
    list; or it serves none of them but has them on its list already (also when, with no
    pilot on duty, it takes no new work). Gives back whether the VV stays so, and ``mine``.
    (The RV's area, altitudes and sensors are the shape's, of the version just read.)"""
    host = vv.host_rv
    if host is None or host.status != VehicleStatus.ACTIVE:
        return False, []
    if not takes_work(host, require_pilot=require_pilot):
        return bool(open_tasks) and all(t.vehicle_id == host.pk for t in open_tasks), []
    caps = shape.caps.get(host.pk) or dataclasses.replace(
        vehicle_caps(host), no_fly=shape.airspace.zones
    )
    mine = _servable(caps, open_tasks)
    if mine and not shape.overlaps.get(host.pk):
        tasks_assign(tasks=mine, vehicle=host, vvm=vvm)
        return True, mine
    return not mine and any(t.vehicle_id == host.pk for t in open_tasks), mine


def _move_to(
    vv: VirtualVehicle, vehicle: Vehicle, served: list[Task], open_tasks: Sequence[Task], vvm: VVM
) -> None:
    """The VV moves to the RV that serves its next tasks (``served`` of ``open_tasks``)."""
    vv_release_tasks(vv=vv, vvm=vvm, open_tasks=open_tasks)
    vv_record_migration(vv=vv, to=vehicle, reason="its next task", vvm=vvm)
    if vvm.keeps_context(vehicle.pk):
        # The RV's host runs in this process: the VV is there at once, its tasks on the RV's
        # list (what the RV's host would do with it next, without a message).
        vv.status = VVStatus.RUNNING
        tasks_assign(tasks=served, vehicle=vehicle, vvm=vvm)
        return
    vv.status = VVStatus.MIGRATING
    vvm.dispatcher.vv_arrived(vv.id, on=HostRef(rv_id=vehicle.pk))


def _servable(caps: VehicleCaps, tasks: Sequence[Task]) -> list[Task]:
    return [t for t in tasks if caps.can_serve(request_of(t))]


# Another RV must be this much sooner (seconds of the mapper's cost) before a VV that its RV
# could serve moves over: no ping-pong between RVs of overlapping areas over a few seconds.
HANDOVER_MARGIN_S = 5.0


def _due_in(vv: VirtualVehicle, vvm: VVM) -> Callable[[Task], float | None]:
    """How long from now each of the VV's tasks has until its deadline (its request time plus
    the VV's customer's class's target; None without a class)."""
    service_class = vv.customer.service_class  # (read with the VV on the task path)
    if service_class is None:
        return lambda task: None
    terms, now = ClassTerms.of(service_class.weight, service_class.p95_s), vvm.clock.now_s()
    return lambda task: terms.due_in(task.requested_s, now)


def _stays(
    host: Vehicle,
    tasks: Sequence[Task],
    mine: Sequence[Task],
    fleet: Sequence[VehicleCaps],
    decisions: Sequence[MapDecision],
    due: Callable[[Task], float | None],
) -> bool:
    """Whether the VV's RV keeps the tasks it can serve (``mine`` of ``tasks``, whose mapper's
    ``decisions`` are in the same order): unless another RV that can serve as many of them
    would serve them at a cost lower by HANDOVER_MARGIN_S (where areas overlap), or in time
    where this one would be late (``due``: each task's time to its deadline)."""
    kept = {id(t) for t in mine}
    best = _best_vehicle(mine, [d for t, d in zip(tasks, decisions, strict=True) if id(t) in kept])
    if best is None or best.id == host.pk:
        return True
    own = next((c for c in fleet if c.id == host.pk), None)
    if own is None or not own.active:
        return False
    requests = [request_of(t) for t in mine]
    if not all(best.can_serve(r) for r in requests):
        return True
    ours = [own.rank(r, due(t)) for r, t in zip(requests, mine, strict=True)]
    theirs = [best.rank(r, due(t)) for r, t in zip(requests, mine, strict=True)]
    if any(
        late and not other_late for (late, _), (other_late, _) in zip(ours, theirs, strict=True)
    ):
        return False
    return sum(cost for _, cost in theirs) + HANDOVER_MARGIN_S >= sum(cost for _, cost in ours)


def _partly_answered(vv: VirtualVehicle, pending: PendingRequest) -> bool:
    return JournalEntry.objects.filter(
        vv=vv, seq=vv.journal_length - 1, entry__q=pending.q
    ).exists()


def request_of(task: Task) -> TaskRequest:
    return TaskRequest(task.lat, task.lng, task.alt, task.tolerance_m, tuple(task.sensors))


def _best_vehicle(tasks: Sequence[Task], decisions: Sequence[MapDecision]) -> VehicleCaps | None:
    """The active RV serving most of the tasks (``decisions``: the mapper's for each, in the
    same order); among equals the best ranked for the first."""
    score: dict[int, int] = {}
    rank: dict[int, tuple[int, int]] = {}
    by_id: dict[int, VehicleCaps] = {}
    for order, decision in enumerate(decisions):
        for position, caps in enumerate(decision.candidates):
            score[caps.id] = score.get(caps.id, 0) + 1
            rank.setdefault(caps.id, (order, position))
            by_id[caps.id] = caps
    if not score:
        return None
    best = min(score, key=lambda vid: (-score[vid], rank[vid], by_id[vid].name))
    return by_id[best]


def tasks_assign(*, tasks: Iterable[Task], vehicle: Vehicle, vvm: VVM) -> None:
    """Put these open tasks on the RV's list (a task not saved yet: its caller saves it so)."""
    now = vvm.clock.now_s()
    moved = [t for t in tasks if t.vehicle_id != vehicle.pk]
    if not moved:
        return
    for task in moved:
        task.vehicle, task.assigned_s = vehicle, now
    tasks_assigned([t.pk for t in moved if t.pk is not None], vehicle_id=vehicle.pk, now=now)
    if vvm.local_fleet is None or not vvm.local_fleet.assigned(vehicle.pk, moved):
        vvm.dispatcher.vehicle_changed(vehicle.pk)


def vv_release_tasks(
    *, vv: VirtualVehicle, vvm: VVM, open_tasks: Sequence[Task] | None = None
) -> None:
    """Take the VV's open tasks off the RVs they were planned on; ``open_tasks``: all of them,
    as the caller has them (in the same transaction)."""
    if open_tasks is None:
        held = vv.tasks.filter(status=TaskStatus.OPEN, vehicle__isnull=False)
        vehicles = set(held.values_list("vehicle_id", flat=True))
        held.update(vehicle=None)
    else:
        taken = [t for t in open_tasks if t.vehicle_id is not None]
        vehicles = {t.vehicle_id for t in taken}
        saved = [t.pk for t in taken if t.pk is not None]
        if saved:
            Task.objects.filter(pk__in=saved).update(vehicle=None)
        for task in taken:
            task.vehicle = None
    for vehicle_id in sorted(vehicles):
        vvm.dispatcher.vehicle_changed(vehicle_id)


def vv_reject_request(
    *,
    vv: VirtualVehicle,
    pending: PendingRequest,
    rejected: list[tuple[Task, MapDecision]],
    vvm: VVM,
    open_tasks: Sequence[Task] | None = None,
) -> None:
    """Answer the pending request with an error: no RV can serve (the first of) ``rejected``.
    Every open task of the request ends rejected (``open_tasks``: as the caller has them)."""
    now = vvm.clock.now_s()
    task, decision = rejected[0]
    message = decision.reason or "no vehicle can serve the task"
    if pending.kind == "batch":
        message = f"task {task.index} of the batch: {message}"
    journal_append(
        vv, answer_reject(pending, time_ms=vvm.clock.epoch_ms(now), message=message), vvm
    )
    if open_tasks is None:
        open_tasks = list(vv.tasks.filter(q=pending.q, status=TaskStatus.OPEN))
    tasks_reject(vv=vv, tasks=open_tasks, message=message, now=now, vvm=vvm)
    vv.pending = None
    logger.info("task rejected", extra={"vv": str(vv.id), "reason": message})


def tasks_reject(
    *, vv: VirtualVehicle, tasks: Sequence[Task], message: str, now: float, vvm: VVM
) -> None:
    """These open tasks of the VV end rejected with ``message`` (those not saved yet only in
    memory, their caller saves them so); the map hears of the saved ones."""
    for task in tasks:
        task.status, task.message, task.done_s = TaskStatus.REJECTED, message, now
    saved = [t.pk for t in tasks if t.pk is not None]
    if saved:
        Task.objects.filter(pk__in=saved).update(
            status=TaskStatus.REJECTED, message=message, done_s=now
        )
        vvm.announce(lambda: [task_event(t, vv.customer_id) for t in tasks if t.pk])


def vv_record_migration(
    *, vv: VirtualVehicle, to: GroundStation | Vehicle, reason: str, vvm: VVM
) -> None:
    """The VV moves to this host (the caller saves the VV): recorded for its track, the map
    and the customer."""
    vvm.settle_host(vv.host_rv)  # the track of those aboard either RV, as it was
    if isinstance(to, Vehicle):
        vvm.settle_host(to)
    source: GroundStation | Vehicle | None = vv.host_rv or vv.host_gs
    to_kind = HostKind.RV if isinstance(to, Vehicle) else HostKind.GS
    if source is not None:
        # An RV's last reported position (its depot before its first flight).
        here, there = source.position, to.position
        migration = Migration(
            vv=vv,
            from_kind=HostKind.RV if isinstance(source, Vehicle) else HostKind.GS,
            from_name=source.name,
            to_kind=to_kind,
            to_name=to.name,
            at_s=vvm.clock.now_s(),
            reason=reason,
            from_lat=here.lat,
            from_lng=here.lng,
            to_lat=there.lat,
            to_lng=there.lng,
        )
        rows_add([migration])  # its key is read by the end of the unit of work
        vvm.announce_at_commit(lambda: migration_event(migration, vv.customer_id))
    if isinstance(to, Vehicle):
        vv.host_rv, vv.host_gs = to, None
    else:
        vv.host_rv, vv.host_gs = None, to
    # The VV's warm context stays here, also when the VV leaves this process: should it come
    # back, the context catches up on the steps made elsewhere (the runtime's resume reads
    # their answers from the journal) instead of replaying from the program's first line.
    logger.info(
        "vv %r migrated from %s to %s",
        vv.name,
        getattr(source, "name", "nowhere"),
        to.name,
        extra={
            "vv": str(vv.id),
            "customer": customer_named(vv),
            "from": getattr(source, "name", None),
            "to": to.name,
            "reason": reason,
        },
    )


def vv_migrate_to_ground_station(
    *, vv: VirtualVehicle, reason: str, vvm: VVM, open_tasks: Sequence[Task] | None = None
) -> None:
    """Move the VV off its RV to the nearest ground station (the caller saves the VV)."""
    near = vv.host_rv.position if vv.host_rv is not None else None
    gs = ground_station_for(vv, near=near)
    if gs is None:
        return
    vv_release_tasks(vv=vv, vvm=vvm, open_tasks=open_tasks)
    vv_record_migration(vv=vv, to=gs, reason=reason, vvm=vvm)
    vv.status = VVStatus.MIGRATING
    vvm.dispatcher.vv_arrived(vv.id, on=HostRef(gs_id=gs.pk))
