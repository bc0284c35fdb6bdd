"""Reading maintenance (staff data): what is due on each RV and its battery, and the batteries'
logbooks. The rules are plain functions (``cycle_step``, ``due_level``); the services that act
on them (grounding, recording) are ``vvm_worker.services.maintenance``.

What is due, per interval (``MaintenanceInterval``) that applies to an RV (its own, its kind's,
every RV's): since the last record of that interval for the RV, or else since its first flight
(with no flight: since the interval was made), the flight hours (the flights' durations), the
flights (landed) and the days; for its battery, the cycles since the last record of the interval
for the battery (else all its cycles), and its cycles against the retirement limit. Due soon at
DUE_SOON of a limit, overdue at 100 %.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from django.db.models import Count, Max, Min, Q, QuerySet, Sum

from fleet.models import (
    CYCLE_FULL_PCT,
    CYCLE_LOW_PCT,
    Battery,
    Flight,
    MaintenanceInterval,
    MaintenanceRecord,
    Vehicle,
)

DUE_SOON = 0.9  # of a limit


def cycle_step(*, below_low: bool, pct: float) -> tuple[bool, bool]:
    """The cycle rule, one charge reading at a time: ``below_low`` is whether the battery was
    seen below CYCLE_LOW_PCT since it last counted a cycle. Returns (below_low now, whether
    this reading counts a cycle): a reading above CYCLE_FULL_PCT after a low one counts one."""
    if pct < CYCLE_LOW_PCT:
        return True, False
    if pct > CYCLE_FULL_PCT and below_low:
        return False, True
    return below_low, False


def due_level(used: float, limit: float) -> str | None:
    """ "overdue" at 100 % of the limit, "due_soon" at DUE_SOON, else None."""
    if used >= limit:
        return "overdue"
    if used >= DUE_SOON * limit:
        return "due_soon"
    return None


@dataclass(frozen=True)
class Due:
    """One limit of an interval that is due soon or overdue: {name, kind, used, limit}."""

    name: str
    kind: str  # hours, flights, days, cycles
    used: float
    limit: float
    interval_id: int
    battery: str | None = None  # the battery's name, for cycles
    retire: bool = False  # the retirement limit (a battery past it is retired)

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "used": self.used,
            "limit": self.limit,
            "interval": self.interval_id,
            "battery": self.battery,
            "retire": self.retire,
        }


@dataclass
class MaintenanceDue:
    """What is due on an RV (and its battery now): due soon, overdue, and its battery's name
    when that battery is retired (or past its retirement cycles)."""

    due_soon: list[Due] = field(default_factory=list)
    overdue: list[Due] = field(default_factory=list)
    battery: str | None = None
    battery_retired: bool = False

    @property
    def grounding(self) -> str | None:
        """Why the RV must not fly (the status reason it is grounded with), or None."""
        if self.battery_retired:
            return f"battery {self.battery} retired: swap it"
        inspections = list(dict.fromkeys(d.name for d in self.overdue if not d.retire))
        if inspections:
            return f"grounded: {', '.join(inspections)} overdue"
        return None

    def as_dict(self) -> dict[str, list[dict[str, Any]]]:
        return {
            "due_soon": [d.as_dict() for d in self.due_soon],
            "overdue": [d.as_dict() for d in self.overdue],
        }


def intervals_for(vehicle: Vehicle, intervals: Iterable[MaintenanceInterval]) -> list[Any]:
    """The intervals that apply to the RV: its own, its kind's and every RV's."""
    return [
        i
        for i in intervals
        if i.vehicle_id == vehicle.pk
        or (i.vehicle_id is None and (not i.kind or i.kind == vehicle.kind))
    ]


def _add(due: MaintenanceDue, entry: Due) -> None:
    level = due_level(entry.used, entry.limit)
    if level == "overdue":
        due.overdue.append(entry)
    elif level == "due_soon":
        due.due_soon.append(entry)


def fleet_maintenance(
    *, vehicles: Sequence[Vehicle], now: dt.datetime
) -> dict[int, MaintenanceDue]:
    """What is due on each of these RVs and their batteries now, by the RV's id; a few
    statements whatever the number of RVs (none with no interval)."""
    intervals = list(MaintenanceInterval.objects.all())
    result = {v.pk: MaintenanceDue() for v in vehicles}
    ids = list(result)
    batteries = {b.vehicle_id: b for b in Battery.objects.filter(vehicle_id__in=ids)}
    for vehicle_id, battery in batteries.items():
        result[vehicle_id].battery = battery.name
        result[vehicle_id].battery_retired = battery.retired is not None
    if not intervals or not ids:
        return result
    last = {
        (row["vehicle_id"], row["interval_id"]): row["at"]
        for row in MaintenanceRecord.objects.filter(vehicle_id__in=ids, interval__isnull=False)
        .values("vehicle_id", "interval_id")
        .annotate(at=Max("at"))
    }
    first = dict(
        Flight.objects.filter(vehicle_id__in=ids)
        .values("vehicle_id")
        .annotate(first=Min("started"))
        .values_list("vehicle_id", "first")
    )
    # Each (RV, interval) counts the RV's flights since its own time: one aggregate for all.
    since: dict[tuple[int, int], dt.datetime] = {}
    sums: dict[str, Any] = {}
    for vehicle in vehicles:
        for interval in intervals_for(vehicle, intervals):
            if (interval.every_hours, interval.every_flights, interval.every_days) == (None,) * 3:
                continue  # a battery's interval only
            start = last.get((vehicle.pk, interval.pk)) or first.get(vehicle.pk)
            start = start or interval.created
            since[(vehicle.pk, interval.pk)] = start
            landed = Q(vehicle_id=vehicle.pk, started__gte=start, ended__isnull=False)
            sums[f"n_{vehicle.pk}_{interval.pk}"] = Count("id", filter=landed)
            sums[f"s_{vehicle.pk}_{interval.pk}"] = Sum("duration_s", filter=landed)
    flown = Flight.objects.filter(vehicle_id__in=ids).aggregate(**sums) if sums else {}
    battery_last = _cycles_at_records([b.pk for b in batteries.values()])
    for vehicle in vehicles:
        due = result[vehicle.pk]
        for interval in intervals_for(vehicle, intervals):
            key = (vehicle.pk, interval.pk)
            if key in since:
                n = flown.get(f"n_{vehicle.pk}_{interval.pk}") or 0
                hours = (flown.get(f"s_{vehicle.pk}_{interval.pk}") or 0.0) / 3600.0
                days = max(0.0, (now - since[key]).total_seconds() / 86400.0)
                if interval.every_hours is not None:
                    _add(due, Due(interval.name, "hours", round(hours, 2), interval.every_hours,
                                  interval.pk))  # fmt: skip
                if interval.every_flights is not None:
                    _add(due, Due(interval.name, "flights", n, interval.every_flights, interval.pk))
                if interval.every_days is not None:
                    _add(due, Due(interval.name, "days", round(days, 1), interval.every_days,
                                  interval.pk))  # fmt: skip
            pack = batteries.get(vehicle.pk)
            if pack is not None:
                for entry in battery_due(
                    battery=pack,
                    interval=interval,
                    cycles_at_record=battery_last.get((pack.pk, interval.pk)),
                ):
                    _add(due, entry)
        if any(d.retire for d in due.overdue):
            due.battery_retired = True
    return result


def _cycles_at_records(battery_ids: list[int]) -> dict[tuple[int, int], int | None]:
    """The batteries' cycles at the last record of each interval, by (battery, interval):
    cycles only grow, so the last record's are the most."""
    if not battery_ids:
        return {}
    return {
        (row["battery_id"], row["interval_id"]): row["cycles"]
        for row in MaintenanceRecord.objects.filter(
            battery_id__in=battery_ids, interval__isnull=False
        )
        .values("battery_id", "interval_id")
        .annotate(cycles=Max("battery_cycles"))
    }


def battery_due(
    *, battery: Battery, interval: MaintenanceInterval, cycles_at_record: int | None
) -> list[Due]:
    """The battery's cycle limits of the interval: cycles since the interval's last record
    for it (``cycles_at_record``: its cycles then; None: never recorded), and its cycles
    against the retirement limit."""
    entries = []
    if interval.every_cycles is not None:
        used = battery.cycles - (cycles_at_record or 0)
        entries.append(
            Due(interval.name, "cycles", max(0, used), interval.every_cycles, interval.pk,
                battery=battery.name)
        )  # fmt: skip
    if interval.retire_cycles is not None:
        entries.append(
            Due(f"{interval.name}: retirement", "cycles", battery.cycles, interval.retire_cycles,
                interval.pk, battery=battery.name, retire=True)
        )  # fmt: skip
    return entries


def vehicle_maintenance(*, vehicle: Vehicle, now: dt.datetime) -> MaintenanceDue:
    """What is due on one RV and its battery now (``fleet_maintenance``)."""
    return fleet_maintenance(vehicles=[vehicle], now=now)[vehicle.pk]


def battery_list(*, retired: bool | None = None) -> QuerySet[Battery]:
    """Every battery by name, with the RV it is in (or only retired ones, or those in use)."""
    batteries = Battery.objects.select_related("vehicle").order_by("name")
    if retired is not None:
        batteries = batteries.filter(retired__isnull=not retired)
    return batteries


def battery_due_list(*, batteries: Sequence[Battery]) -> dict[int, list[Due]]:
    """What is due on each battery by its id (due soon or overdue, retirement included): the
    intervals of the RV it is in, every RV's intervals for one in no RV."""
    intervals = list(MaintenanceInterval.objects.filter(
        Q(every_cycles__isnull=False) | Q(retire_cycles__isnull=False)
    ))  # fmt: skip
    result: dict[int, list[Due]] = {b.pk: [] for b in batteries}
    if not intervals or not batteries:
        return result
    recorded = _cycles_at_records(list(result))
    for battery in batteries:
        applies = (
            intervals_for(battery.vehicle, intervals)
            if battery.vehicle is not None
            else [i for i in intervals if i.vehicle_id is None and not i.kind]
        )
        for interval in applies:
            for entry in battery_due(
                battery=battery,
                interval=interval,
                cycles_at_record=recorded.get((battery.pk, interval.pk)),
            ):
                if due_level(entry.used, entry.limit) is not None:
                    result[battery.pk].append(entry)
    return result


def battery_logbook(*, battery: Battery) -> dict[str, Any]:
    """A battery's logbook: cycles (CYCLE_RULE), flights, flight hours, lowest charge seen,
    the RV it is in and since when, whether and when it retired."""
    return {
        "id": battery.pk,
        "name": battery.name,
        "serial": battery.serial,
        "autopilot_id": battery.autopilot_id,
        "vehicle": battery.vehicle.name if battery.vehicle is not None else None,
        "installed": battery.installed,
        "cycles": battery.cycles,
        "flights": battery.flights,
        "flight_hours": round(battery.flight_s / 3600.0, 3),
        "lowest_pct": battery.lowest_pct,
        "retired": battery.retired,
    }


def vehicle_batteries(*, vehicle: Vehicle) -> list[dict[str, Any]]:
    """The logbook of the RV's battery now (a list: none while it has none)."""
    return [battery_logbook(battery=b) for b in Battery.objects.filter(vehicle=vehicle)]
