"""Reading the fleet: the SDC a user may use, vehicles and ground stations (staff data)."""

from __future__ import annotations

from collections.abc import Iterable

from django.db.models import Count, Q, QuerySet

from accounts.models import User
from accounts.selectors import customer_catalog
from fleet.models import GroundStation, SensorType, Vehicle
from missions.models import ENDED_STATUSES


class UnknownSensors(LookupError):
    """Names that are not in the SDC."""

    def __init__(self, names: Iterable[str]) -> None:
        self.names = sorted(names)
        super().__init__(
            "unknown SDC entries: "
            + ", ".join(repr(n) for n in self.names)
            + " (GET /api/v1/sensors/ lists the catalog)"
        )


def sensor_list_for_user(*, user: User) -> QuerySet[SensorType]:
    """The SDC entries a user may use: all of them for staff, the customer's catalog (its
    allowed entries, privileged ones only for privileged customers) for a customer's user,
    none for anyone else."""
    entries = SensorType.objects.order_by("name")
    if user.is_staff:
        return entries
    if user.customer is None:
        return entries.none()
    names = [e["name"] for e in customer_catalog(customer=user.customer)]
    return entries.filter(name__in=names)


def sensors_by_name(*, names: Iterable[str]) -> list[SensorType]:
    """The SDC entries of these names, in the order given; UnknownSensors names any missing."""
    wanted = list(dict.fromkeys(names))
    found = {s.name: s for s in SensorType.objects.filter(name__in=wanted)}
    missing = [n for n in wanted if n not in found]
    if missing:
        raise UnknownSensors(missing)
    return [found[n] for n in wanted]


def vehicle_list(*, status: str | None = None) -> QuerySet[Vehicle]:
    """Every RV, removed ones included (or those in one status), with its sensors and the
    number of VVs aboard."""
    vehicles = (
        Vehicle.objects.prefetch_related("sensors")
        .annotate(vvs_aboard=Count("vvs", filter=~Q(vvs__status__in=ENDED_STATUSES)))
        .order_by("name")
    )
    return vehicles.filter(status=status) if status else vehicles


def ground_station_list() -> QuerySet[GroundStation]:
    """Every ground station with the number of VVs it holds that have not ended."""
    return GroundStation.objects.annotate(
        vvs_here=Count("vvs", filter=~Q(vvs__status__in=ENDED_STATUSES))
    ).order_by("name")
