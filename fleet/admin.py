from typing import Any

from django.contrib import admin, messages
from django.db.models import QuerySet
from django.http import HttpRequest

from fleet.models import GroundStation, SensorType, Vehicle, VehicleStatus
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    GroundStationConfig,
    VehicleConfig,
    ground_station_create,
    ground_station_update,
    vehicle_create,
    vehicle_set_status,
    vehicle_update,
)


def _config(form: Any, fields: Any, only_changed: bool) -> Any:
    """The form's values of a service's config fields (those the user changed, on an edit)."""
    names = form.changed_data if only_changed else form.cleaned_data
    return {f: form.cleaned_data[f] for f in names if f in fields.__annotations__}


@admin.register(SensorType)
class SensorTypeAdmin(admin.ModelAdmin):
    list_display = ["name", "kind", "unit", "privileged"]
    list_filter = ["kind", "privileged"]
    search_fields = ["name"]


@admin.register(GroundStation)
class GroundStationAdmin(admin.ModelAdmin):
    """Ground stations; a new one starts the VVs that waited for one."""

    list_display = ["name", "lat", "lng", "alt"]
    search_fields = ["name"]

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        if change:
            config = _config(form, GroundStationConfig, only_changed=True)
            ground_station_update(station=obj, config=config)
        else:
            config = _config(form, GroundStationConfig, only_changed=False)
            obj.pk = ground_station_create(config=config, vvm=platform_vvm()).pk


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

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        # Through the services: a new RV takes work at once; one whose reach changed hands
        # over what it can no longer serve.
        sensors = [s.name for s in form.cleaned_data.get("sensors", ())]
        if change:
            vehicle_update(
                vehicle=obj,
                config=_config(form, VehicleConfig, only_changed=True),
                sensors=sensors if "sensors" in form.changed_data else None,
                vvm=platform_vvm(),
            )
        else:
            config = _config(form, VehicleConfig, only_changed=False)
            obj.pk = vehicle_create(config=config, sensors=sensors, vvm=platform_vvm()).pk

    def save_related(self, request: HttpRequest, form: Any, formsets: Any, change: bool) -> None:
        pass  # save_model's service saved the sensors; a vehicle has no inlines

    def _set_status(
        self, request: HttpRequest, queryset: QuerySet[Vehicle], status: VehicleStatus
    ) -> None:
        vvm = platform_vvm()
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
