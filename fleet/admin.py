from typing import Any

from django.contrib import admin, messages
from django.db.models import QuerySet
from django.http import HttpRequest

from fleet.models import GroundStation, SensorType, Vehicle, VehicleStatus
from fleet.services import REACH_FIELDS


@admin.register(SensorType)
class SensorTypeAdmin(admin.ModelAdmin):
    list_display = ["name", "kind", "unit", "privileged"]
    list_filter = ["kind", "privileged"]
    search_fields = ["name"]


@admin.register(GroundStation)
class GroundStationAdmin(admin.ModelAdmin):
    list_display = ["name", "lat", "lng", "alt"]
    search_fields = ["name"]


def _platform_vvm() -> Any:
    from vvm_worker.platform import platform_vvm

    return platform_vvm()


@admin.register(Vehicle)
class VehicleAdmin(admin.ModelAdmin):
    """RVs: their limits and sensors; status changes go through the actions, which move the
    VVs aboard an RV that leaves service to RVs that can serve them."""

    list_display = [
        "name",
        "status",
        "driver",
        "max_speed_mps",
        "phase",
        "tasks_done",
        "worker_seen",
    ]
    list_filter = ["status", "driver"]
    search_fields = ["name"]
    filter_horizontal = ["sensors"]
    readonly_fields = [
        "status",
        "lat",
        "lng",
        "alt",
        "phase",
        "distance_m",
        "flight_s",
        "tasks_done",
        "worker_seen",
    ]
    actions = ["put_into_maintenance", "return_to_service", "remove_from_fleet"]
    fieldsets = [
        (None, {"fields": ["name", "status", "driver", "driver_url"]}),
        (
            "Limits",
            {
                "fields": [
                    ("depot_lat", "depot_lng", "depot_alt"),
                    "area",
                    ("min_altitude_m", "max_altitude_m"),
                    ("max_speed_mps", "climb_rate_mps"),
                    "battery_s",
                    "sensors",
                ]
            },
        ),
        (
            "State",
            {
                "fields": [
                    "phase",
                    ("lat", "lng", "alt"),
                    "distance_m",
                    "flight_s",
                    "tasks_done",
                    "worker_seen",
                ]
            },
        ),
    ]

    def save_related(self, request: HttpRequest, form: Any, formsets: Any, change: bool) -> None:
        # After the sensors are saved: a new RV takes work at once; one whose reach changed
        # hands over what it can no longer serve.
        super().save_related(request, form, formsets, change)
        from vvm_worker.services import vehicle_reconfigured, vehicle_register

        if not change:
            vehicle_register(vehicle=form.instance, vvm=_platform_vvm())
        elif "sensors" in form.changed_data or any(f in form.changed_data for f in REACH_FIELDS):
            vehicle_reconfigured(vehicle=form.instance, vvm=_platform_vvm())

    def _set_status(
        self, request: HttpRequest, queryset: QuerySet[Vehicle], status: VehicleStatus
    ) -> None:
        from vvm_worker.services import vehicle_set_status

        vvm = _platform_vvm()
        for vehicle in queryset:
            vehicle_set_status(vehicle=vehicle, status=status, vvm=vvm)
        names = ", ".join(v.name for v in queryset)
        self.message_user(request, f"{names}: {status.label.lower()}", messages.SUCCESS)

    @admin.action(description="Put into maintenance (VVs aboard move to other RVs)")
    def put_into_maintenance(self, request: HttpRequest, queryset: QuerySet[Vehicle]) -> None:
        self._set_status(request, queryset, VehicleStatus.MAINTENANCE)

    @admin.action(description="Return to service")
    def return_to_service(self, request: HttpRequest, queryset: QuerySet[Vehicle]) -> None:
        self._set_status(request, queryset, VehicleStatus.ACTIVE)

    @admin.action(description="Remove from the fleet (VVs aboard move to other RVs)")
    def remove_from_fleet(self, request: HttpRequest, queryset: QuerySet[Vehicle]) -> None:
        self._set_status(request, queryset, VehicleStatus.REMOVED)
