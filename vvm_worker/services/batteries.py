"""The batteries the RVs report: which battery is in an RV (by the autopilot's serial or
battery id, or the one in it), the cycle rule and the lowest charge, the flights counted for
the battery in an RV, and a battery's retirement at its cycles. What people do with batteries
and what grounds an RV: ``vvm_worker.services.maintenance``.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from django.db import transaction
from django.db.models import F, Max, Sum

from fleet.maintenance import cycle_step, intervals_for
from fleet.models import Battery, Flight, MaintenanceInterval, Vehicle
from vvm_worker.services.base import logger


def battery_observe(
    *,
    vehicle_id: int,
    pct: float | None,
    battery_id: int | None = None,
    serial: str | None = None,
    now: dt.datetime,
) -> bool:
    """The RV's worker saw its battery's charge ``pct`` (%) at ``now``, with the autopilot's
    battery id (BATTERY_STATUS.id) and serial (SMART_BATTERY_INFO) where it reports them.

    The battery is the one of that serial; else the one in that id's slot of this RV (named
    "<RV> battery <id>"; an operator's named battery in the RV takes the id it is reported
    with); else the RV's battery now (one is made, "<RV> battery", for an RV that has none).
    Another battery than the RV's now is a swap: it is put in. Then the cycle rule
    (``fleet.maintenance.cycle_step``; CYCLE_RULE) and the lowest charge. One read when
    nothing changes; a write only when something does. A battery that reaches its
    retirement cycles is retired.

    Returns whether the RV's maintenance must be checked again (a swap, a retirement): the
    caller that has a VVM calls ``vehicle_check_maintenance``, which grounds the RV or puts it
    back. No VVM here: the RV's worker reports health without one.
    """
    if pct is None:
        return False
    pct = float(pct)
    current = Battery.objects.filter(vehicle_id=vehicle_id).first()
    battery = current
    if serial:
        if current is None or current.serial != serial:
            battery = Battery.objects.filter(serial=serial).first() or _battery_made(
                vehicle_id, serial, serial=serial
            )
    elif battery_id is not None:
        if current is not None and current.autopilot_id is None and not current.serial:
            Battery.objects.filter(pk=current.pk).update(autopilot_id=battery_id)
        elif current is None or current.autopilot_id != battery_id:
            name = f"{_vehicle_name(vehicle_id)} battery {battery_id}"
            battery = _battery_named(vehicle_id, name, autopilot_id=battery_id)
    elif current is None:
        battery = _battery_named(vehicle_id, f"{_vehicle_name(vehicle_id)} battery")
    assert battery is not None
    swapped = battery is not current
    if swapped:
        battery_put_in(vehicle_id=vehicle_id, battery=battery, now=now, audited=False)
        logger.info(
            "vehicle %s: battery %s seen",
            vehicle_id,
            battery.name,
            extra={"vehicle_id": vehicle_id, "battery": battery.name},
        )
    below, counted = cycle_step(below_low=battery.below_low, pct=pct)
    changes: dict[str, Any] = {}
    if below != battery.below_low:
        changes["below_low"] = below
    if counted:
        changes["cycles"] = F("cycles") + 1
    if battery.lowest_pct is None or pct < battery.lowest_pct:
        changes["lowest_pct"] = pct
    if changes:
        Battery.objects.filter(pk=battery.pk).update(**changes)
    retired = counted and _battery_retire_if_due(battery_id=battery.pk, now=now)
    return swapped or retired


def _vehicle_name(vehicle_id: int) -> str:
    return str(Vehicle.objects.values_list("name", flat=True).get(pk=vehicle_id))


def _battery_named(vehicle_id: int, name: str, **fields: Any) -> Battery:
    """The battery of that name, unless it is in another RV (then a new one, numbered)."""
    found = Battery.objects.filter(name=name).first()
    if found is not None and found.vehicle_id in (None, vehicle_id):
        return found
    return _battery_made(vehicle_id, name, **fields)


def _battery_made(vehicle_id: int, name: str, **fields: Any) -> Battery:
    taken = set(Battery.objects.filter(name__startswith=name).values_list("name", flat=True))
    unique, n = name, 1
    while unique in taken:
        n += 1
        unique = f"{name} #{n}"
    return Battery.objects.create(name=unique, **fields)


def battery_put_in(*, vehicle_id: int, battery: Battery, now: dt.datetime, audited: bool) -> None:
    """Put the battery into the RV (taking out the one there, and taking it out of any other
    RV); the RV's flights that ended before count for the one taken out. ``audited``: a
    person's swap, saved so that the audit log keeps it (the autopilot's is not a change anyone
    made)."""
    with transaction.atomic():
        battery_count_flights(vehicle_id=vehicle_id)
        out = Battery.objects.filter(vehicle_id=vehicle_id).exclude(pk=battery.pk)
        if audited:
            for old in out:
                old.vehicle = None
                old.save(update_fields=["vehicle"])
        else:
            out.update(vehicle=None)
        battery.vehicle_id = vehicle_id
        battery.installed = now
        battery.counted_until = now
        if audited:
            battery.save(update_fields=["vehicle", "installed", "counted_until"])
        else:
            Battery.objects.filter(pk=battery.pk).update(
                vehicle_id=vehicle_id, installed=now, counted_until=now
            )


def battery_count_flights(*, vehicle_id: int) -> None:
    """Count the RV's flights that ended since they were last counted for the battery in it
    (its flights and flight time), and name it on those flights that name no battery."""
    battery = Battery.objects.filter(vehicle_id=vehicle_id).first()
    if battery is None:
        return
    since = battery.counted_until or battery.installed or battery.created
    new = Flight.objects.filter(vehicle_id=vehicle_id, ended__isnull=False, ended__gt=since)
    totals = new.aggregate(n=Max("ended"), s=Sum("duration_s"))
    if totals["n"] is None:
        return
    ended = new.filter(ended__lte=totals["n"])
    count = ended.count()
    Battery.objects.filter(pk=battery.pk).update(
        flights=F("flights") + count,
        flight_s=F("flight_s") + (totals["s"] or 0.0),
        counted_until=totals["n"],
    )
    ended.filter(battery_name="").update(battery_name=battery.name)


def _battery_retire_if_due(*, battery_id: int, now: dt.datetime) -> bool:
    """Retire the battery when its cycles reached a retirement limit of its RV's intervals
    (every RV's for one in none). Returns whether it was retired now."""
    battery = Battery.objects.select_related("vehicle").get(pk=battery_id)
    if battery.retired is not None:
        return False
    intervals = MaintenanceInterval.objects.filter(retire_cycles__isnull=False)
    applies = (
        intervals_for(battery.vehicle, intervals)
        if battery.vehicle is not None
        else [i for i in intervals if i.vehicle_id is None and not i.kind]
    )
    limits = [i.retire_cycles for i in applies]
    if not limits or battery.cycles < min(limits):
        return False
    retired = Battery.objects.filter(pk=battery_id, retired__isnull=True).update(retired=now)
    if retired:
        logger.warning(
            "battery %s retired at %d cycles",
            battery.name,
            battery.cycles,
            extra={"battery": battery.name, "vehicle_id": battery.vehicle_id},
        )
    return bool(retired)
