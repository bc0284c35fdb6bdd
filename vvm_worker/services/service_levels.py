"""Service levels, the database side: a customer's class, and whether the fleet keeps a
class's target now (the tasks of its customers read lately and those still open). While a
class misses its target, admission holds back the new VVs of the classes with slack (their
p95 well inside their own target: ``holding_back``), never those of the class that misses,
and asks again when a task of a class ends (``class_held_nudge``) or a ground station
sweeps.

The figures themselves are computed in the pure core ``vvm_worker.level_figures``.
"""

from __future__ import annotations

import uuid
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any

from django.db.models import Q

from accounts.models import ServiceClass, ServiceLevelHold
from fleet.geo import Position
from fleet.kinds import AERIAL
from fleet.models import Vehicle
from fleet.simulation import VehicleSpec
from missions.models import Task, TaskStatus, VirtualVehicle, VVStatus, WaitReason
from missions.waiting import duration_text
from vvm_worker.level_figures import (
    NO_CLASS,
    ClassTerms,
    LevelStats,
    ServiceClassSpec,
    level_stats,
    misses_target,
    percentile,
)
from vvm_worker.planning import (
    DEFAULT_PLANNER,
    Planner,
    TravelTime,
    make_planner,
    standby_position,
)
from vvm_worker.planning.alone import (
    AloneRequest,
    AloneVehicle,
    Reading,
    alone_latencies,
    reading_overhead,
)
from vvm_worker.services.base import VVM

# The tasks read in this many seconds (platform clock) before now say how the fleet keeps a
# class's target now; older ones say how it kept it then.
LEVEL_WINDOW_S = 600.0
# Fewer latencies than this (read lately and still open together) say nothing yet.
LEVEL_MIN_SAMPLES = 20


def class_spec(service_class: ServiceClass | None) -> ServiceClassSpec:
    """A class row as the pure core's spec; ``NO_CLASS`` for None (no target, weight 1)."""
    if service_class is None:
        return NO_CLASS
    return ServiceClassSpec(service_class.name, service_class.p95_s, service_class.weight)


@dataclass(frozen=True)
class ClassLatencies:
    """A class's tasks now: ``recent`` latencies (read within the window, seconds from the
    request to the reading) and ``open_ages`` (how long each open task has waited so far)."""

    recent: list[float]
    open_ages: list[float]


def class_latencies(
    *, service_class_id: int, now_s: float, window_s: float = LEVEL_WINDOW_S
) -> ClassLatencies:
    """The latencies of the tasks of the class's customers read since ``now_s - window_s``
    and the ages of those still open (platform clock): one query. A task read belongs to a
    VV that has not ended or ended after it, so the VVs that ended before the window are not
    read."""
    since = now_s - window_s
    rows = (
        Task.objects.filter(vv__customer__service_class_id=service_class_id)
        .filter(Q(vv__finished_s__isnull=True) | Q(vv__finished_s__gte=since))
        .filter(Q(status=TaskStatus.OPEN) | Q(status=TaskStatus.DONE, done_s__gte=since))
        .order_by()
        .values_list("requested_s", "done_s")
    )
    recent, open_ages = [], []
    for requested_s, done_s in rows:
        if done_s is None:
            open_ages.append(max(0.0, now_s - requested_s))
        else:
            recent.append(done_s - requested_s)
    return ClassLatencies(recent=recent, open_ages=open_ages)


# A class has slack while its p95 is at most this share of its target: its new VVs may then
# be held back for a class that misses its own.
SLACK_SHARE = 0.5
# Why a VV held back waits, in its owner's words (never another customer or class).
HELD_BACK = (
    "held to keep other service levels; your class's target is met "
    "(it starts within {wait} at most)"
)


@dataclass(frozen=True)
class ClassLevel:
    """How the fleet keeps a class's target now: ``p95_s`` over its recent and open tasks
    (None: none), and ``missing`` (beyond the target: admission holds back the classes with
    slack for it)."""

    spec: ServiceClassSpec
    p95_s: float | None
    missing: bool

    @property
    def spare_s(self) -> float:
        """How much longer than now its requests could wait and the class still keep its
        target: what a held VV of the class may wait at most (0 without slack)."""
        if self.spec.p95_s is None or self.missing:
            return 0.0
        return max(0.0, self.spec.p95_s - (self.p95_s or 0.0))

    @property
    def has_slack(self) -> bool:
        """Whether the class keeps its target with room to spare (``SLACK_SHARE``)."""
        if self.spec.p95_s is None or self.missing:
            return False
        return (self.p95_s or 0.0) <= SLACK_SHARE * self.spec.p95_s


def class_level(
    *, service_class: ServiceClass, now_s: float, min_samples: int = LEVEL_MIN_SAMPLES
) -> ClassLevel:
    """Whether the fleet misses the class's target now (``misses_target`` over its tasks read
    lately and still open). A class with no open task is never missing: the fleet has
    caught up with it, and a VV started now is served without waiting behind others."""
    spec = class_spec(service_class)
    seen = class_latencies(service_class_id=service_class.pk, now_s=now_s)
    values = [*seen.recent, *seen.open_ages]
    missing = bool(seen.open_ages) and misses_target(
        spec.p95_s,
        recent_latencies=seen.recent,
        open_ages=seen.open_ages,
        min_samples=min_samples,
    )
    return ClassLevel(spec=spec, p95_s=percentile(values, 95) if values else None, missing=missing)


# Routing looks again at which classes give way at most this often (platform seconds).
GIVE_WAY_LOOK_S = 10.0


def classes_giving_way(*, now_s: float, vvm: VVM) -> frozenset[int | None]:
    """The service classes whose tasks leave the mapper's reserve of RVs to others now
    (`mapping.Reserve`; None stands for the customers without a class): while a class with a
    target that has no slack is being served (a task of it requested within the window), every
    class served that has slack (`ClassLevel.has_slack`) and the customers without a class.
    Empty otherwise: with no class served, or every class with slack, nobody gives way.
    Looked at again at most every GIVE_WAY_LOOK_S of the platform's clock (kept on ``vvm``):
    one query, and one per class served."""
    seen = vvm.giving_way_seen
    if seen is not None and 0.0 <= now_s - seen[0] < GIVE_WAY_LOOK_S:
        return seen[1]
    served = ServiceClass.objects.filter(
        customers__vvs__tasks__requested_s__gte=now_s - LEVEL_WINDOW_S
    ).distinct()
    levels = {c.pk: class_level(service_class=c, now_s=now_s) for c in served}
    pressed = any(v.spec.p95_s is not None and not v.has_slack for v in levels.values())
    giving: frozenset[int | None] = frozenset()
    if pressed:
        giving = frozenset({None, *(pk for pk, level in levels.items() if level.has_slack)})
    vvm.giving_way_seen = (now_s, giving)
    return giving


@dataclass(frozen=True)
class HoldBack:
    """Admission holds back a customer's new VVs: ``level`` is its class's, ``for_classes``
    the classes that miss their targets now."""

    level: ClassLevel
    for_classes: tuple[str, ...]

    def message(self) -> str:
        return HELD_BACK.format(wait=duration_text(self.level.spare_s))

    def used_up(self, *, held_since_s: float | None, now_s: float) -> bool:
        """Whether VVs held since ``held_since_s`` (None: none held yet) have waited as long as
        their class's requests could and it still keep its own target: the hold ends."""
        return held_since_s is not None and now_s - held_since_s >= self.level.spare_s


def holding_back(*, service_class: ServiceClass, now_s: float) -> HoldBack | None:
    """Whether admission holds back the new VVs of a customer of ``service_class`` now: while
    another class misses its target and this one has slack (for how long: ``HoldBack.used_up``).
    Never the class that misses, never a customer without a class. One query per class with
    open tasks."""
    level = class_level(service_class=service_class, now_s=now_s)
    if not level.has_slack:
        return None
    others = ServiceClass.objects.exclude(pk=service_class.pk).filter(
        customers__vvs__tasks__status=TaskStatus.OPEN
    )
    missing = tuple(
        other.name
        for other in others.distinct().order_by("name")
        if class_level(service_class=other, now_s=now_s).missing
    )
    return HoldBack(level, missing) if missing else None


def service_level_hold_keep(*, customer_id: int, hold: HoldBack, held: int, now_s: float) -> None:
    """Admission holds back ``held`` queued VVs of the customer (``hold``): the customer's open
    hold goes on (the most VVs held at once, every class it was held for) or a new one begins
    now. One or two queries."""
    row = ServiceLevelHold.objects.filter(customer_id=customer_id, ended_s__isnull=True).first()
    if row is None:
        if not held:
            return  # its queued VVs started or were cancelled meanwhile: nothing is held
        ServiceLevelHold.objects.create(
            customer_id=customer_id,
            service_class=hold.level.spec.name,
            for_classes=list(hold.for_classes),
            class_p95_s=hold.level.p95_s,
            spare_s=hold.level.spare_s,
            started_s=now_s,
            vvs_held=held,
        )
        return
    for_classes = sorted({*row.for_classes, *hold.for_classes})
    if held > row.vvs_held or for_classes != row.for_classes:
        row.vvs_held, row.for_classes = max(held, row.vvs_held), for_classes
        row.save(update_fields=["vvs_held", "for_classes"])


def service_level_hold_end(*, customer_id: int, now_s: float) -> None:
    """Admission no longer holds the customer's VVs back: its open hold (if any) ends now."""
    ServiceLevelHold.objects.filter(customer_id=customer_id, ended_s__isnull=True).update(
        ended_s=now_s
    )


def class_held_nudge(*, service_class_id: int | None, vvm: VVM, told: int | None = None) -> None:
    """A task of the class ended (read, rejected or cancelled with its VV): a class that
    missed its target may keep it again, and the classes held back for it have used some of
    their slack, so admission looks again at each customer whose queued VVs are held back,
    except ``told`` (a customer the caller asked admission for). One query; nothing for a
    task of no class or when none is held."""
    if service_class_id is None:
        return
    held = (
        VirtualVehicle.objects.filter(
            status=VVStatus.QUEUED,
            waiting_reason=WaitReason.SERVICE_LEVEL,
        )
        .exclude(customer_id=told)
        .order_by("customer_id")
        .values_list("customer_id", flat=True)
        .distinct()
    )
    for customer_id in held:
        vvm.dispatcher.customer_slot_freed(customer_id)


# --- the report: how each customer's class was kept over a period (Part E) ---------------------

# The customer of a report's row per class.
ALL_CUSTOMERS = "(all)"


def service_levels_report(
    *,
    since_s: float | None = None,
    until_s: float | None = None,
    vv_ids: Collection[uuid.UUID] | None = None,
    by_customer: bool = True,
) -> list[LevelStats]:
    """Figures per customer and class (``level_stats``: requests read, median and p95 of the
    latency from request to reading, share within the class's target) of the tasks requested
    from ``since_s`` (inclusive) to ``until_s`` (exclusive) on the platform clock (None: no
    bound) and read; ``vv_ids``: only these VVs' tasks (a simulation's). ``by_customer``
    False: one row per class, its customer ``ALL_CUSTOMERS``. One query; a customer is
    counted in the class it has now. Sorted by class name, then customer."""
    rows = Task.objects.filter(status=TaskStatus.DONE, done_s__isnull=False)
    if since_s is not None:
        rows = rows.filter(requested_s__gte=since_s)
    if until_s is not None:
        rows = rows.filter(requested_s__lt=until_s)
    if vv_ids is not None:
        rows = rows.filter(vv_id__in=list(vv_ids))
    specs: dict[tuple[Any, ...], ServiceClassSpec] = {}

    def latency(
        customer: str, name: str | None, p95_s: float | None, weight: float | None, wait: float
    ) -> tuple[str, ServiceClassSpec, float]:
        who = customer if by_customer else ALL_CUSTOMERS
        if name is None:
            return who, NO_CLASS, wait
        key = (name, p95_s, weight)
        spec = specs.get(key)
        if spec is None:  # one spec per class, not one per row
            spec = specs[key] = ServiceClassSpec(name, p95_s, 1.0 if weight is None else weight)
        return who, spec, wait

    return level_stats(
        latency(customer, name, p95_s, weight, done_s - requested_s)
        for customer, name, p95_s, weight, requested_s, done_s in rows.order_by().values_list(
            "vv__customer__name",
            "vv__customer__service_class__name",
            "vv__customer__service_class__p95_s",
            "vv__customer__service_class__weight",
            "requested_s",
            "done_s",
        )
    )


def service_levels_classed(*, vv_ids: Collection[uuid.UUID]) -> bool:
    """Whether any customer of these VVs has a service class (``simulate`` then shows the
    figures per class)."""
    return VirtualVehicle.objects.filter(
        pk__in=list(vv_ids), customer__service_class__isnull=False
    ).exists()


# --- the report's additions per class: what it would get alone, and the holds ------------------


@dataclass(frozen=True)
class HoldShown:
    """A hold as the report shows it: ``held_s`` is how long it held within the period (an
    open one: until the period's end or now, whichever is first)."""

    customer: str
    service_class: str
    for_classes: tuple[str, ...]
    started_s: float
    ended_s: float | None
    held_s: float
    vvs_held: int
    class_p95_s: float | None
    spare_s: float


def service_level_holds(*, since_s: float, until_s: float, now_s: float) -> list[HoldShown]:
    """Every hold that held during the period (from ``since_s`` to ``until_s``, platform
    clock), oldest first. One query."""
    rows = (
        ServiceLevelHold.objects.filter(started_s__lt=until_s)
        .filter(Q(ended_s__isnull=True) | Q(ended_s__gt=since_s))
        .select_related("customer")
        .order_by("started_s", "pk")
    )
    return [
        HoldShown(
            customer=row.customer.name,
            service_class=row.service_class,
            for_classes=tuple(row.for_classes),
            started_s=row.started_s,
            ended_s=row.ended_s,
            held_s=max(
                0.0,
                min(until_s, now_s if row.ended_s is None else row.ended_s)
                - max(since_s, row.started_s),
            ),
            vvs_held=row.vvs_held,
            class_p95_s=row.class_p95_s,
            spare_s=row.spare_s,
        )
        for row in rows
    ]


@dataclass(frozen=True)
class ClassFigures:
    """A class's row of the report: what it got (``got``), what it would have got alone
    (``alone``, ``planning.alone``'s estimate from the period's requests; None: none read
    by an RV), its customers' holds (``holds``, seconds ``held_s``) and the holds of other
    classes made for it (``holds_for_it``)."""

    got: LevelStats
    alone: LevelStats | None
    holds: int = 0
    held_s: float = 0.0
    holds_for_it: int = 0

    def as_dict(self) -> dict[str, object]:
        alone = None
        if self.alone is not None:
            figures = self.alone.as_dict()
            alone = {k: figures[k] for k in ALONE_FIELDS}
        return {
            **self.got.as_dict(),
            "alone": alone,
            "holds": {
                "count": self.holds,
                "held_s": round(self.held_s, 3),
                "for_this_class": self.holds_for_it,
            },
        }


ALONE_FIELDS = ("requests", "median_s", "p95_s", "within_target", "meets_target")


def service_levels_by_class(
    *,
    since_s: float | None = None,
    until_s: float | None = None,
    holds: Sequence[HoldShown] = (),
) -> list[ClassFigures]:
    """The report per class (``service_levels_report(by_customer=False)``) with each class's
    latency alone (``class_alone_stats``) and the ``holds`` of the period counted per class:
    those of its customers and those made for it. Three queries."""
    alone = class_alone_stats(since_s=since_s, until_s=until_s)
    rows = []
    for got in service_levels_report(since_s=since_s, until_s=until_s, by_customer=False):
        own = [h for h in holds if h.service_class == got.service_class]
        rows.append(
            ClassFigures(
                got=got,
                alone=alone.get(got.service_class),
                holds=len(own),
                held_s=sum(h.held_s for h in own),
                holds_for_it=sum(1 for h in holds if got.service_class in h.for_classes),
            )
        )
    return rows


def class_alone_stats(
    *, since_s: float | None = None, until_s: float | None = None
) -> dict[str, LevelStats]:
    """Per class, the figures its requests of the period would have had if the fleet served
    nobody else (``planning.alone``): the RVs that read tasks in the period replay the class's
    requests, each sent where the mapper would send it among the RVs whose area covers it,
    from their depots, with the default planner and their own travel times, each reading
    costing what a reading cost the RV in the period (``reading_overhead`` over all its
    readings). Two queries."""
    rows = Task.objects.filter(status=TaskStatus.DONE, done_s__isnull=False, vehicle__isnull=False)
    if since_s is not None:
        rows = rows.filter(requested_s__gte=since_s)
    if until_s is not None:
        rows = rows.filter(requested_s__lt=until_s)
    read: dict[int, list[Reading]] = {}
    asked: dict[ServiceClassSpec, list[AloneRequest]] = {}
    specs: dict[tuple[Any, ...], ServiceClassSpec] = {}
    for (
        pk,
        vehicle_id,
        lat,
        lng,
        alt,
        requested_s,
        assigned_s,
        done_s,
        name,
        p95_s,
        weight,
    ) in rows.order_by().values_list(
        "pk",
        "vehicle_id",
        "lat",
        "lng",
        "alt",
        "requested_s",
        "assigned_s",
        "done_s",
        "vv__customer__service_class__name",
        "vv__customer__service_class__p95_s",
        "vv__customer__service_class__weight",
    ):
        where = Position(lat, lng, alt)
        read.setdefault(vehicle_id, []).append(Reading(where, requested_s, done_s))
        key = (name, p95_s, weight)
        spec = specs.get(key)
        if spec is None:
            spec = specs[key] = NO_CLASS if name is None else ServiceClassSpec(name, p95_s, weight)
        terms = ClassTerms.of(weight, p95_s)
        asked.setdefault(spec, []).append(
            AloneRequest(
                pk,
                where,
                requested_s,
                ready_s=requested_s if assigned_s is None else max(requested_s, assigned_s),
                read_by=vehicle_id,
                weight=terms.weight,
                deadline_s=terms.deadline(requested_s),
            )
        )
    fleet = [_alone_vehicle(v, read[k]) for k, v in Vehicle.objects.in_bulk(list(read)).items()]
    latencies: list[tuple[str, ServiceClassSpec, float]] = []
    for spec, requests in asked.items():  # a replay a class: fresh planners, RVs at their depots
        waits = alone_latencies(requests, fleet)
        latencies += [(ALL_CUSTOMERS, spec, wait) for wait in waits.values()]
    return {stats.service_class: stats for stats in level_stats(latencies)}


def _alone_vehicle(vehicle: Vehicle, readings: Sequence[Reading]) -> AloneVehicle:
    leg = TravelTime(vehicle.max_speed_mps, vehicle.climb_rate_mps, vehicle.dive_rate_mps)
    low, high = vehicle.min_altitude_m, vehicle.max_altitude_m

    def covers(where: Position) -> bool:
        return low <= where.alt <= high and vehicle.covers(where)

    def new_planner() -> Planner:
        return make_planner(DEFAULT_PLANNER, travel_time=leg, time_limit_s=ALONE_PLAN_S)

    standby = None
    if new_planner().stands_by:
        standby = standby_position(
            vehicle.area_polygon,
            [r.position.alt for r in readings],
            min_altitude_m=low,
            max_altitude_m=high,
        )
    return AloneVehicle(
        vehicle.pk,
        vehicle.depot,
        leg,
        new_planner,
        overhead_s=reading_overhead(readings, leg=leg),
        covers=covers,
        standby=standby,
        # Aerial RVs take off as the simulator's (and the MAVLink driver's) do.
        takeoff_alt_m=VehicleSpec.takeoff_alt_m if vehicle.kind == AERIAL else None,
    )


# The most a replay spends planning one decision (many open tasks: a class that cannot be
# served alone in time; a few are planned exactly whatever this is).
ALONE_PLAN_S = 0.02
