"""Changing the fleet through the REST API: adding and configuring RVs, ground stations.

Putting an RV into maintenance, back into service or removing it is
``vvm_worker.services.vehicle_set_status``; giving a new RV work is
``vvm_worker.services.vehicle_register``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypedDict

from django.core.exceptions import ValidationError
from django.db import transaction

from fleet.models import GroundStation, SensorType, Vehicle
from fleet.selectors import UnknownSensors, sensors_by_name
from missions.models import ENDED_STATUSES, VirtualVehicle, VVStatus
from vvm_worker.services import VVM, vehicle_reconfigured, vehicle_register

# Changing any of these may leave tasks planned on the RV that it can no longer serve.
REACH_FIELDS = ("area", "min_altitude_m", "max_altitude_m")


class VehicleConfig(TypedDict, total=False):
    """What a provider configures on an RV (model field names)."""

    name: str
    driver: str
    driver_url: str
    depot_lat: float
    depot_lng: float
    depot_alt: float
    area: list[list[float]]
    min_altitude_m: float
    max_altitude_m: float
    max_speed_mps: float
    climb_rate_mps: float
    battery_s: float | None


class GroundStationConfig(TypedDict, total=False):
    """What a provider configures on a ground station (model field names)."""

    name: str
    lat: float
    lng: float
    alt: float


class GroundStationBusy(RuntimeError):
    """The ground station holds VVs that have not ended, so it cannot go."""

    def __init__(self, station: GroundStation, count: int) -> None:
        super().__init__(f"{station.name} holds {count} VV(s) that have not ended")
        self.station = station
        self.count = count


def _sensor_entries(names: Sequence[str]) -> list[SensorType]:
    try:
        return sensors_by_name(names=names)
    except UnknownSensors as exc:
        raise ValidationError({"sensors": str(exc)}) from None


def _validate_vehicle(vehicle: Vehicle) -> None:
    # The database constraint would only say "constraint violated"; name the field instead.
    if (
        vehicle.max_altitude_m is not None
        and vehicle.min_altitude_m is not None
        and vehicle.max_altitude_m < vehicle.min_altitude_m
    ):
        raise ValidationError(
            {"max_altitude_m": f"must not be below min_altitude_m ({vehicle.min_altitude_m:g} m)"}
        )
    vehicle.full_clean()  # field ranges, a unique name, and the area (Vehicle.clean)


def vehicle_create(*, config: VehicleConfig, sensors: Sequence[str], vvm: VVM) -> Vehicle:
    """Add an RV to the fleet, in service: it takes work at once (``vehicle_register``).

    Raises ValidationError naming the field: a bad area (not closed, fewer than 3 points,
    crossing itself), an altitude range upside down, a name in use, unknown sensor names.
    """
    entries = _sensor_entries(sensors)
    with transaction.atomic():
        vehicle = Vehicle(**config)
        _validate_vehicle(vehicle)
        vehicle.save()
        vehicle.sensors.set(entries)
    vehicle_register(vehicle=vehicle, vvm=vvm)
    return vehicle


def vehicle_update(
    *, vehicle: Vehicle, config: VehicleConfig, sensors: Sequence[str] | None, vvm: VVM
) -> Vehicle:
    """Change an RV's configuration; ``sensors`` None keeps its sensors.

    When its reach changes (area, altitude range, sensors), the tasks planned on it are taken
    off it and the VVs aboard route them again: they stay if it can still serve them and move
    to an RV that can otherwise; an RV in service with a larger reach takes work at once.
    Raises ValidationError naming the field, like ``vehicle_create``.
    """
    entries = None if sensors is None else _sensor_entries(sensors)
    reach_changed = entries is not None or any(f in config for f in REACH_FIELDS)
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        for name, value in config.items():
            setattr(vehicle, name, value)
        _validate_vehicle(vehicle)
        vehicle.save()
        if entries is not None:
            vehicle.sensors.set(entries)
    if reach_changed:
        vehicle_reconfigured(vehicle=vehicle, vvm=vvm)
    return vehicle


def ground_station_create(*, config: GroundStationConfig, vvm: VVM) -> GroundStation:
    """Add a ground station. VVs waiting in a queue because there was none start now.

    Raises ValidationError naming the field (position out of range, name in use).
    """
    with transaction.atomic():
        station = GroundStation(**config)
        station.full_clean()
        station.save()
        waiting = (
            VirtualVehicle.objects.filter(status=VVStatus.QUEUED)
            .values_list("customer_id", flat=True)
            .distinct()
        )
        for customer_id in sorted(waiting):
            vvm.dispatcher.customer_slot_freed(customer_id)
    return station


def ground_station_update(*, station: GroundStation, config: GroundStationConfig) -> GroundStation:
    """Rename or move a ground station. Raises ValidationError naming the field."""
    with transaction.atomic():
        station = GroundStation.objects.select_for_update().get(pk=station.pk)
        for name, value in config.items():
            setattr(station, name, value)
        station.full_clean()
        station.save()
    return station


def ground_station_delete(*, station: GroundStation) -> None:
    """Remove a ground station; GroundStationBusy while it holds VVs that have not ended."""
    with transaction.atomic():
        station = GroundStation.objects.select_for_update().get(pk=station.pk)
        busy = station.vvs.exclude(status__in=ENDED_STATUSES).count()
        if busy:
            raise GroundStationBusy(station, busy)
        station.delete()
