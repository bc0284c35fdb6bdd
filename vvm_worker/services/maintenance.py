"""Batteries and maintenance: the batteries the RVs report (cycles, lowest charge, flights),
battery swaps, maintenance records, and grounding an RV whose maintenance is overdue or whose
battery is retired (and putting it back once someone records the maintenance or swaps the
battery).

Grounding is ``vehicle_set_status`` to maintenance with a reason this module alone writes
("grounded: 25-hour inspection overdue", "battery B7 retired: swap it"): the VVs aboard move on,
the RV takes no new work, and so a MAVLink RV's worker does not arm it. Only an RV grounded
with such a reason is put back into service here: never one a person put into maintenance.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from django.core.exceptions import ValidationError
from django.db import transaction
from django.utils import timezone

from fleet.maintenance import MaintenanceDue, intervals_for, vehicle_maintenance
from fleet.models import (
    Battery,
    MaintenanceInterval,
    MaintenanceRecord,
    Vehicle,
    VehicleStatus,
)
from vvm_worker.services.base import VVM, logger
from vvm_worker.services.batteries import battery_count_flights, battery_put_in
from vvm_worker.services.fleet import VehicleRemoved, vehicle_set_status

GROUNDED = "grounded: "
RETIRED = " retired: swap it"
BACK = "back in service: its maintenance was recorded"


def is_grounding(reason: str) -> bool:
    """Whether a status reason is one this module grounds an RV with (not a person's)."""
    return reason.startswith(GROUNDED) or (
        reason.startswith("battery ") and reason.endswith(RETIRED)
    )


# --- what people do ------------------------------------------------------------------------------


def battery_swap(*, vehicle: Vehicle, name: str, by: Any, vvm: VVM, notes: str = "") -> Battery:
    """``by`` swapped the RV's battery for the one named ``name`` (one known, or a new one by
    that name; taken out of another RV it was in), recorded as maintenance of the RV
    ("battery swapped: <name>", in the audit log). An RV grounded for its retired battery
    goes back into service (``vehicle_check_maintenance``). Raises ValidationError naming
    ``name`` (empty, or a retired battery), VehicleRemoved for a removed RV."""
    name = name.strip()
    if not name:
        raise ValidationError({"name": "name the battery put in"})
    now = timezone.now()
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == VehicleStatus.REMOVED:
            raise VehicleRemoved(vehicle)
        battery = Battery.objects.select_for_update().filter(name=name).first()
        if battery is not None and battery.retired is not None:
            raise ValidationError(
                {"name": f"battery {name} is retired ({battery.cycles} cycles): put in another"}
            )
        if battery is None:
            battery = Battery(name=name)
            battery.full_clean()
            battery.save()
        if battery.vehicle_id != vehicle.pk:
            if battery.vehicle_id is not None:
                battery_count_flights(vehicle_id=battery.vehicle_id)
            battery_put_in(vehicle_id=vehicle.pk, battery=battery, now=now, audited=True)
        MaintenanceRecord.objects.create(
            vehicle=vehicle,
            battery=battery,
            what=f"battery swapped: {name}"[:200],
            by=by,
            by_name=by.get_username(),
            at=now,
            notes=notes,
            battery_cycles=battery.cycles,
        )
        logger.info(
            "vehicle %s: battery %s put in by %s",
            vehicle.name,
            name,
            by.get_username(),
            extra={"vehicle": vehicle.name, "battery": name},
        )
    vehicle_check_maintenance(vehicle_id=vehicle.pk, vvm=vvm)
    battery.refresh_from_db()
    return battery


def maintenance_record(
    *,
    vehicle: Vehicle | None = None,
    battery: Battery | None = None,
    interval: MaintenanceInterval | None = None,
    by: Any,
    what: str = "",
    notes: str = "",
    vvm: VVM,
) -> MaintenanceRecord:
    """``by`` did maintenance on the RV or the battery (or both): the interval's (which starts
    it again) or ``what`` in words, now, with ``notes``; kept in the audit log. An interval
    with battery cycles records the RV's battery with its cycles. Then the RV's maintenance is
    checked: grounded for this, it goes back into service (``vehicle_check_maintenance``).
    Raises ValidationError naming the field: neither RV nor battery, neither interval nor
    ``what``, an interval that does not apply to the RV."""
    what = what.strip()
    if vehicle is None and battery is None:
        raise ValidationError({"vehicle": "name the vehicle or the battery maintained"})
    if interval is None and not what:
        raise ValidationError({"what": "say what was done, or name the interval"})
    if interval is not None and vehicle is not None and not intervals_for(vehicle, [interval]):
        raise ValidationError({"interval": f"{interval.name} is not one of {vehicle.name}'s"})
    if (
        interval is not None
        and battery is None
        and vehicle is not None
        and (interval.every_cycles is not None or interval.retire_cycles is not None)
    ):
        battery = Battery.objects.filter(vehicle=vehicle).first()
    with transaction.atomic():
        record = MaintenanceRecord(
            vehicle=vehicle,
            battery=battery,
            interval=interval,
            what=what or (interval.name if interval is not None else ""),
            by=by,
            by_name=by.get_username(),
            at=timezone.now(),
            notes=notes,
            battery_cycles=battery.cycles if battery is not None else None,
        )
        record.full_clean()
        record.save()
    logger.info(
        "maintenance recorded: %s",
        record.what,
        extra={
            "vehicle": vehicle.name if vehicle is not None else None,
            "battery": battery.name if battery is not None else None,
            "by": record.by_name,
        },
    )
    checked = vehicle.pk if vehicle is not None else battery.vehicle_id  # type: ignore[union-attr]
    if checked is not None:
        vehicle_check_maintenance(vehicle_id=checked, vvm=vvm)
    return record


# --- grounding -----------------------------------------------------------------------------------


def vehicle_check_maintenance(
    *, vehicle_id: int, vvm: VVM, now: dt.datetime | None = None
) -> MaintenanceDue:
    """Look at the RV's maintenance now: called when one of its flights ends (its flights are
    counted for its battery first), after a maintenance record or a battery swap, and daily
    (``vehicles_check_maintenance``) for the N-days intervals.

    Overdue (``fleet.maintenance``), or with a battery past its retirement cycles (which is
    retired), the RV is grounded: into maintenance with the reason ("grounded: 25-hour
    inspection overdue", "battery B7 retired: swap it"; its VVs move on, it takes no new work).
    Grounded and nothing overdue any more, it goes back into service. An RV a person put into
    maintenance stays there; a removed one is left alone. Returns what is due."""
    now = now or timezone.now()
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().filter(pk=vehicle_id).first()
        if vehicle is None or vehicle.status == VehicleStatus.REMOVED:
            return MaintenanceDue()
        battery_count_flights(vehicle_id=vehicle_id)
        due = vehicle_maintenance(vehicle=vehicle, now=now)
        if due.battery_retired:
            Battery.objects.filter(vehicle_id=vehicle_id, retired__isnull=True).update(retired=now)
        reason = due.grounding
        if reason is not None and vehicle.status != VehicleStatus.MAINTENANCE:
            vehicle_set_status(
                vehicle=vehicle, status=VehicleStatus.MAINTENANCE, vvm=vvm, reason=reason
            )
            logger.warning("vehicle %s: %s", vehicle.name, reason, extra={"vehicle": vehicle.name})
        elif reason is not None and is_grounding(vehicle.status_reason):
            if vehicle.status_reason != reason:  # grounded for something else now
                vehicle.status_reason = reason
                vehicle.save(update_fields=["status_reason", "updated"])
        elif (
            reason is None
            and vehicle.status == VehicleStatus.MAINTENANCE
            and is_grounding(vehicle.status_reason)
        ):
            vehicle_set_status(
                vehicle=vehicle,
                status=VehicleStatus.ACTIVE,
                vvm=vvm,
                reason=BACK,
                expected=VehicleStatus.MAINTENANCE,
            )
    return due


def vehicles_check_maintenance(*, vvm: VVM, now: dt.datetime | None = None) -> list[str]:
    """``vehicle_check_maintenance`` for every RV in the fleet (the daily look, for the
    N-days intervals); returns the names of those grounded now."""
    grounded = []
    for vehicle_id, name in (
        Vehicle.objects.exclude(status=VehicleStatus.REMOVED)
        .order_by("pk")
        .values_list("pk", "name")
    ):
        if vehicle_check_maintenance(vehicle_id=vehicle_id, vvm=vvm, now=now).grounding:
            grounded.append(name)
    return grounded
