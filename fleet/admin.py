from django.contrib import admin

from fleet.models import GroundStation, SensorType, Vehicle


@admin.register(SensorType)
class SensorTypeAdmin(admin.ModelAdmin):
    list_display = ["name", "kind", "unit", "privileged"]
    list_filter = ["kind", "privileged"]
    search_fields = ["name"]


@admin.register(GroundStation)
class GroundStationAdmin(admin.ModelAdmin):
    list_display = ["name", "lat", "lng", "alt"]
    search_fields = ["name"]


@admin.register(Vehicle)
class VehicleAdmin(admin.ModelAdmin):
    list_display = ["name", "status", "driver", "max_speed_mps", "phase", "tasks_done"]
    list_filter = ["status", "driver"]
    search_fields = ["name"]
    filter_horizontal = ["sensors"]
    readonly_fields = ["lat", "lng", "alt", "phase", "distance_m", "flight_s", "tasks_done"]
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
            {"fields": ["phase", ("lat", "lng", "alt"), "distance_m", "flight_s", "tasks_done"]},
        ),
    ]
