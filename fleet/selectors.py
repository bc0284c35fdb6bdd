"""Reading the fleet: SDC entries by name, vehicles and ground stations (staff data)."""

from __future__ import annotations

from collections.abc import Iterable

from django.db.models import QuerySet

from fleet.models import GroundStation, SensorType, Vehicle


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


def vehicle_list(*, status: str | None = None) -> QuerySet[Vehicle]:
    """Every RV, removed ones included (or those in one status), with its sensors."""
    vehicles = Vehicle.objects.prefetch_related("sensors").order_by("name")
    return vehicles.filter(status=status) if status else vehicles


def ground_station_list() -> QuerySet[GroundStation]:
    """Every ground station, by name."""
    return GroundStation.objects.order_by("name")
