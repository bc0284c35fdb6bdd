"""Reading the fleet: SDC entries by name, vehicles and ground stations (staff data)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from django.db.models import Count, Max, Q, QuerySet, Sum

from fleet.geo import Position
from fleet.kinds import a_vehicle
from fleet.models import (
    Flight,
    GroundStation,
    NoFlyZone,
    RallyPoint,
    SensorType,
    Vehicle,
    VehicleStatus,
)
from fleet.service_area import Exclusion, Reach, service_area_geojson


class UnknownSensors(LookupError):
    """Names that are not in the SDC."""

    def __init__(self, names: Iterable[str]) -> None:
        self.names = sorted(names)
        super().__init__(
            "unknown SDC entries: "
            + ", ".join(repr(n) for n in self.names)
            + " (GET /api/v1/sensors/ lists the catalog)"
        )


def sensors_by_name(*, names: Iterable[str]) -> list[SensorType]:
    """The SDC entries of these names, in the order given; UnknownSensors names any missing."""
    wanted = list(dict.fromkeys(names))
    found = {s.name: s for s in SensorType.objects.filter(name__in=wanted)}
    missing = [n for n in wanted if n not in found]
    if missing:
        raise UnknownSensors(missing)
    return [found[n] for n in wanted]


def sensors_not_carried(*, kind: str, sensors: Iterable[SensorType]) -> str | None:
    """What a vehicle of the kind cannot carry among these SDC entries, in words naming
    each (``SensorType.kinds``), or None when it can carry them all."""
    refused = [
        f"{s.name!r} (carried by {', '.join(s.kinds)} vehicles only)"
        for s in sensors
        if not s.carried_by(kind)
    ]
    if not refused:
        return None
    return f"{a_vehicle(kind)} cannot carry " + ", ".join(refused)


def sensor_carriers(*, sensor: SensorType) -> QuerySet[Vehicle]:
    """The RVs in the fleet (not removed) that carry the SDC entry, by name."""
    return sensor.vehicles.exclude(status=VehicleStatus.REMOVED).order_by("name")


def vehicle_list(*, status: str | None = None) -> QuerySet[Vehicle]:
    """Every RV, removed ones included (or those in one status), with its sensors."""
    vehicles = (
        Vehicle.objects.select_related("pilot_on_duty")
        .prefetch_related("sensors", "pilots")
        .order_by("name")
    )
    return vehicles.filter(status=status) if status else vehicles


def ground_station_list() -> QuerySet[GroundStation]:
    """Every ground station, by name."""
    return GroundStation.objects.order_by("name")


@dataclass(frozen=True)
class VehicleFence:
    """What an RV's autopilot is to enforce: its operation area (a closed ring of [lat, lng])
    and altitude range, the no-fly zones' rings, and the rally points."""

    area: list[list[float]]
    min_altitude_m: float
    max_altitude_m: float
    exclusions: list[list[list[float]]]
    rally: list[Position]


def vehicle_fence(*, vehicle: Vehicle) -> VehicleFence:
    """The fence of this RV's autopilot. An autopilot's exclusion polygon holds at every
    altitude: it gets the no-fly zones that hold at every altitude the RV may fly; a zone of
    a narrower band is the platform's alone to keep (the mapper serves no task inside it)."""
    zones = NoFlyZone.objects.filter(min_altitude_m__lte=vehicle.min_altitude_m).filter(
        Q(max_altitude_m__isnull=True) | Q(max_altitude_m__gte=vehicle.max_altitude_m)
    )
    return VehicleFence(
        area=vehicle.area,
        min_altitude_m=vehicle.min_altitude_m,
        max_altitude_m=vehicle.max_altitude_m,
        exclusions=[zone.area for zone in zones],
        rally=[point.position for point in RallyPoint.objects.all()],
    )


# In service: serving, or back by themselves (a recharge, a link that returns); not in
# maintenance (a person's decision) and not removed. The service area and a dry run's copy of
# the fleet are made of these.
IN_SERVICE = (VehicleStatus.ACTIVE, VehicleStatus.CHARGING, VehicleStatus.OFFLINE)


def vehicles_in_service() -> QuerySet[Vehicle]:
    """The RVs in service (IN_SERVICE), with their sensors, in the order they were added."""
    return Vehicle.objects.filter(status__in=IN_SERVICE).prefetch_related("sensors").order_by("pk")


def service_area() -> dict[str, Any]:
    """Where the platform can serve tasks now, for customers: the operation areas of the RVs
    in service merged per altitude band, and the no-fly zones, as a GeoJSON FeatureCollection
    (``fleet.service_area.service_area_geojson``). It names no vehicle."""
    reaches = [
        Reach(v.area_polygon, v.min_altitude_m, v.max_altitude_m)
        for v in Vehicle.objects.filter(status__in=IN_SERVICE).only(
            "area", "min_altitude_m", "max_altitude_m"
        )
    ]
    zones = [
        Exclusion(z.area_polygon, z.min_altitude_m, z.max_altitude_m)
        for z in NoFlyZone.objects.order_by("pk")
    ]
    return service_area_geojson(reaches, zones)


# --- flights and the logbook (staff data) ------------------------------------------------------


def flight_list(
    *,
    vehicle_id: int | None = None,
    since: dt.datetime | None = None,
    until: dt.datetime | None = None,
) -> QuerySet[Flight]:
    """Flights newest first, of one RV or all, that took off within [since, until)."""
    flights = Flight.objects.select_related("vehicle").order_by("-started", "-id")
    if vehicle_id is not None:
        flights = flights.filter(vehicle_id=vehicle_id)
    if since is not None:
        flights = flights.filter(started__gte=since)
    if until is not None:
        flights = flights.filter(started__lt=until)
    return flights


def vehicle_logbook(*, vehicle: Vehicle) -> dict[str, Any]:
    """An RV's logbook: its flights, hours, distance, take-offs and landings, last flight (from
    its recorded flights; one still in the air counts as a take-off, not yet a landing)."""
    flights = Flight.objects.filter(vehicle=vehicle)
    totals = flights.aggregate(
        take_offs=Count("id"),
        landings=Count("id", filter=Q(ended__isnull=False)),
        flight_s=Sum("duration_s"),
        distance_m=Sum("distance_m"),
        last=Max("started"),
    )
    return {
        "flights": totals["landings"],
        "take_offs": totals["take_offs"],
        "landings": totals["landings"],
        "flight_hours": round((totals["flight_s"] or 0.0) / 3600.0, 3),
        "distance_km": round((totals["distance_m"] or 0.0) / 1000.0, 3),
        "last_flight": totals["last"],
        # A take-off without its landing yet: the flight under way.
        "in_flight": totals["take_offs"] > totals["landings"],
    }
