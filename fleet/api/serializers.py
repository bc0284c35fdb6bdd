"""Input and output shapes of the SDC, vehicle and ground-station endpoints."""

from __future__ import annotations

from typing import Any

from django.utils import timezone
from drf_spectacular.utils import extend_schema_field
from rest_framework import serializers

from cpcc_site.api import StrictCharField, StrictFloatField, StrictIntegerField
from fleet.maintenance import vehicle_maintenance
from fleet.models import Driver, GroundStation, SensorType, Vehicle, VehicleKind
from vvm_worker.services import GroundStationConfig, VehicleConfig


def _check_lat_lng(lat: float, lng: float, where: str) -> None:
    if not -90.0 <= lat <= 90.0:
        raise serializers.ValidationError(f"{where}: latitude {lat:g} is outside -90..90")
    if not -180.0 <= lng <= 180.0:
        raise serializers.ValidationError(f"{where}: longitude {lng:g} is outside -180..180")


LATITUDE = {"type": "number", "minimum": -90, "maximum": 90, "description": "latitude, degrees"}
LONGITUDE = {"type": "number", "minimum": -180, "maximum": 180, "description": "longitude, degrees"}
ALTITUDE = {"type": "number", "description": "altitude, m above ground"}


@extend_schema_field(
    {"type": "array", "prefixItems": [LATITUDE, LONGITUDE, ALTITUDE], "minItems": 2, "maxItems": 3}
)
class PositionField(serializers.ListField):
    """``[lat, lng]`` or ``[lat, lng, alt]``; the schema gives each coordinate its range."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(child=StrictFloatField(), min_length=2, max_length=3, **kwargs)


@extend_schema_field(
    {"type": "array", "prefixItems": [LATITUDE, LONGITUDE], "minItems": 2, "maxItems": 2}
)
class LatLngField(serializers.ListField):
    """A point of an area: ``[lat, lng]``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(child=StrictFloatField(), min_length=2, max_length=2, **kwargs)


def _position_field(help_text: str) -> serializers.ListField:
    return PositionField(help_text=help_text)


class SensorOutSerializer(serializers.ModelSerializer):
    """An SDC entry as ``VV.sensor.list()`` shows it (``description`` equals ``name``)."""

    description = StrictCharField(source="name")

    class Meta:
        model = SensorType
        fields = ["name", "description", "kind", "unit", "params"]


class StaffSensorOutSerializer(SensorOutSerializer):
    """An SDC entry as staff see it: also whether only privileged customers may use it, and
    which vehicle kinds can carry it."""

    kinds = serializers.ListField(
        child=serializers.ChoiceField(choices=VehicleKind.choices),
        read_only=True,
        help_text="The vehicle kinds that can carry it; empty: every kind.",
    )

    class Meta(SensorOutSerializer.Meta):
        fields = [*SensorOutSerializer.Meta.fields, "privileged", "kinds"]


class VehicleInSerializer(serializers.Serializer):
    """An RV's configuration: where it may fly, how, with which sensors."""

    name = StrictCharField(max_length=80)
    driver = serializers.ChoiceField(choices=Driver.choices, required=False)
    driver_url = StrictCharField(
        max_length=200,
        required=False,
        allow_blank=True,
        help_text="MAVLink connection, e.g. udpin:0.0.0.0:14550.",
    )
    depot = _position_field("[lat, lng] or [lat, lng, alt]: where it takes off and lands.")
    area = serializers.ListField(
        child=LatLngField(),
        min_length=4,
        error_messages={
            "min_length": "needs at least 3 distinct points, closed by repeating the first "
            "(at least {min_length} points)"
        },
        help_text="Operation area: a closed ring of [lat, lng] points (the last repeats the "
        "first), at least 3 distinct points, not crossing itself.",
    )
    kind = serializers.ChoiceField(
        choices=VehicleKind.choices,
        required=False,
        help_text="How it moves (default aerial); its kind bounds its altitudes and speed: "
        "ground and surface vehicles stay at 0 m, only underwater ones go below 0 (depth).",
    )
    min_altitude_m = StrictFloatField(
        required=False, help_text="Metres above home; below 0 is depth (underwater only)."
    )
    max_altitude_m = StrictFloatField(help_text="Metres above home (0 for ground and surface).")
    max_speed_mps = StrictFloatField(min_value=0.1)
    climb_rate_mps = StrictFloatField(
        min_value=0.1,
        required=False,
        help_text="Climb and descent rate; for an underwater vehicle, how fast it rises.",
    )
    dive_rate_mps = StrictFloatField(
        min_value=0.1,
        required=False,
        allow_null=True,
        help_text="Underwater vehicles: how fast it dives; null: its climb rate.",
    )
    turn_rate_dps = StrictFloatField(
        min_value=1.0,
        required=False,
        allow_null=True,
        help_text="Ground and surface vehicles: how fast it turns in place, degrees a second; "
        "null: its kind's default.",
    )
    battery_s = StrictFloatField(
        min_value=1.0, required=False, allow_null=True, help_text="Flight endurance, seconds."
    )
    sensors = serializers.ListField(
        child=StrictCharField(), required=False, help_text="SDC entry names."
    )
    sensor_sources = serializers.DictField(
        child=serializers.DictField(),
        required=False,
        help_text='Where a sensor\'s readings come from, by SDC entry name: {"source": "field" | '
        '"telemetry" | "named_value" | "camera" | "plugin", ...} (docs/mavlink.md); a sensor not named '
        "reads the simulated field.",
    )

    def validate_depot(self, value: list[float]) -> list[float]:
        _check_lat_lng(value[0], value[1], "depot")
        return value

    def validate_area(self, value: list[list[float]]) -> list[list[float]]:
        for n, (lat, lng) in enumerate(value):
            _check_lat_lng(lat, lng, f"point {n}")
        return value

    def config(self) -> VehicleConfig:
        """The validated input as model fields (depot split into its coordinates)."""
        data: dict[str, Any] = {k: v for k, v in self.validated_data.items() if k != "sensors"}
        if "depot" in data:
            depot = data.pop("depot")
            data["depot_lat"], data["depot_lng"] = depot[0], depot[1]
            data["depot_alt"] = depot[2] if len(depot) > 2 else 0.0
        return VehicleConfig(**data)  # type: ignore[typeddict-item]

    def sensor_names(self) -> list[str] | None:
        """The sensors asked for, or None when the input does not mention them."""
        names = self.validated_data.get("sensors")
        return None if names is None else list(names)


class DueSerializer(serializers.Serializer):
    """One limit of a maintenance interval that is due soon or overdue."""

    name = serializers.CharField(help_text="The interval's name (its retirement: ': retirement').")
    kind = serializers.ChoiceField(choices=["hours", "flights", "days", "cycles"])
    used = StrictFloatField(help_text="Flight hours, flights, days or battery cycles so far.")
    limit = StrictFloatField()
    interval = StrictIntegerField(help_text="The interval's id.")
    battery = serializers.CharField(allow_null=True, help_text="The battery's name (cycles).")
    retire = serializers.BooleanField(help_text="The battery's retirement limit.")


class MaintenanceSerializer(serializers.Serializer):
    """What is due on an RV and its battery: due soon (from 90 % of a limit) and overdue
    (an overdue RV is grounded until someone records the maintenance)."""

    due_soon = DueSerializer(many=True)
    overdue = DueSerializer(many=True)


class VehicleOutSerializer(serializers.ModelSerializer):
    """An RV: its configuration, its status and what its control loop last reported."""

    depot = serializers.SerializerMethodField(help_text="[lat, lng, alt]")
    position = serializers.SerializerMethodField(
        help_text="[lat, lng, alt] as last reported, or null before its first report."
    )
    sensors = serializers.SlugRelatedField(slug_field="name", many=True, read_only=True)
    vvs_aboard = StrictIntegerField(
        read_only=True, default=0, help_text="VVs on it that have not ended."
    )
    health = serializers.DictField(
        read_only=True,
        help_text=(
            "What its worker last saw: link (up, down, simulated), armed, mode, battery_pct, "
            "fence (loaded, none), took_over (a pilot's or failsafe's mode, or null)."
        ),
    )
    pilots = serializers.SlugRelatedField(
        slug_field="username",
        many=True,
        read_only=True,
        help_text="The pilots who may operate it and take it on duty.",
    )
    pilot_on_duty = serializers.SlugRelatedField(
        slug_field="username",
        read_only=True,
        help_text="Its pilot in command now, or null.",
    )
    maintenance = serializers.SerializerMethodField(
        help_text="What is due on it and its battery: due soon (from 90 % of a limit) and "
        "overdue (it is grounded until someone records the maintenance)."
    )

    class Meta:
        model = Vehicle
        fields = [
            "id",
            "name",
            "kind",
            "status",
            "status_reason",
            "status_changed",
            "health",
            "health_changed",
            "command",
            "command_requested",
            "command_taken",
            "driver",
            "driver_url",
            "depot",
            "area",
            "min_altitude_m",
            "max_altitude_m",
            "max_speed_mps",
            "climb_rate_mps",
            "dive_rate_mps",
            "turn_rate_dps",
            "battery_s",
            "sensors",
            "sensor_sources",
            "position",
            "phase",
            "distance_m",
            "flight_s",
            "tasks_done",
            "vvs_aboard",
            "pilots",
            "pilot_on_duty",
            "updated",
            "maintenance",
        ]

    @extend_schema_field(MaintenanceSerializer)
    def get_maintenance(self, vehicle: Vehicle) -> dict[str, Any]:
        # The view reads the page's RVs at once (context "maintenance", by id).
        known = self.context.get("maintenance")
        due = known.get(vehicle.pk) if known is not None else None
        if due is None:
            due = vehicle_maintenance(vehicle=vehicle, now=timezone.now())
        return due.as_dict()

    def get_depot(self, vehicle: Vehicle) -> list[float]:
        return [vehicle.depot_lat, vehicle.depot_lng, vehicle.depot_alt]

    def get_position(self, vehicle: Vehicle) -> list[float] | None:
        if vehicle.lat is None or vehicle.lng is None:
            return None
        return [vehicle.lat, vehicle.lng, vehicle.alt or 0.0]


class GroundStationInSerializer(serializers.Serializer):
    """A ground station: its name and where it is."""

    name = StrictCharField(max_length=80)
    position = _position_field("[lat, lng] or [lat, lng, alt].")

    def validate_position(self, value: list[float]) -> list[float]:
        _check_lat_lng(value[0], value[1], "position")
        return value

    def config(self) -> GroundStationConfig:
        """The validated input as model fields."""
        config = GroundStationConfig()
        if "name" in self.validated_data:
            config["name"] = self.validated_data["name"]
        if "position" in self.validated_data:
            position = self.validated_data["position"]
            config["lat"], config["lng"] = position[0], position[1]
            config["alt"] = position[2] if len(position) > 2 else 0.0
        return config


class GroundStationOutSerializer(serializers.ModelSerializer):
    """A ground station and how many VVs that have not ended it holds."""

    position = serializers.SerializerMethodField(help_text="[lat, lng, alt]")
    vvs_here = StrictIntegerField(
        read_only=True, default=0, help_text="VVs on it that have not ended."
    )

    class Meta:
        model = GroundStation
        fields = ["id", "name", "position", "vvs_here"]

    def get_position(self, station: GroundStation) -> list[float]:
        return [station.lat, station.lng, station.alt]


class HandOverSerializer(serializers.Serializer):
    """Whom the RV goes to: another of its pilots, or nobody (left out)."""

    to = StrictCharField(
        required=False,
        max_length=150,
        help_text="The user name of the pilot who takes over; left out: nobody.",
    )


class DutyGroupSerializer(HandOverSerializer):
    """Several RVs at once (all or none); handing over, to whom (``to``)."""

    vehicles = serializers.ListField(
        child=serializers.IntegerField(min_value=1, max_value=2**63 - 1),
        min_length=1,
        max_length=500,
        help_text="The vehicles' ids.",
    )


class BatteryLogbookSerializer(serializers.Serializer):
    """A battery's logbook. Cycles: a charge from below 50 % to above 90 % counts one (a
    battery seen below 50 % and later above 90 %; then it must go below 50 % again)."""

    id = StrictIntegerField()
    name = serializers.CharField()
    serial = serializers.CharField(help_text="The autopilot's serial, or empty.")
    autopilot_id = StrictIntegerField(allow_null=True, help_text="BATTERY_STATUS.id, or null.")
    vehicle = serializers.CharField(allow_null=True, help_text="The RV it is in now, or null.")
    installed = serializers.DateTimeField(allow_null=True)
    cycles = StrictIntegerField()
    flights = StrictIntegerField()
    flight_hours = StrictFloatField()
    lowest_pct = StrictFloatField(allow_null=True, help_text="The lowest charge seen, %.")
    retired = serializers.DateTimeField(allow_null=True, help_text="Retired then, or null.")


class LogbookSerializer(serializers.Serializer):
    """An RV's logbook, from its recorded flights."""

    flights = StrictIntegerField(help_text="Flights that ended (landed, or lost).")
    take_offs = StrictIntegerField()
    landings = StrictIntegerField()
    flight_hours = StrictFloatField()
    distance_km = StrictFloatField()
    last_flight = serializers.DateTimeField(allow_null=True, help_text="Its last take-off.")
    in_flight = serializers.BooleanField()
    batteries = BatteryLogbookSerializer(
        many=True, help_text="The logbook of its battery now (none while it has none)."
    )


class BatteryOutSerializer(BatteryLogbookSerializer):
    """A battery's logbook and its limits due soon or overdue."""

    due = DueSerializer(many=True)


class MaintenanceRecordInSerializer(serializers.Serializer):
    """Maintenance done on the RV: an interval's (by its id) or what was done in words."""

    interval = StrictIntegerField(
        required=False, min_value=1, help_text="The maintenance interval's id (GET the vehicle's "
        "maintenance for those due)."
    )  # fmt: skip
    what = StrictCharField(required=False, max_length=200, help_text="What was done, in words.")
    notes = StrictCharField(required=False, allow_blank=True, max_length=5000)

    def validate(self, data: dict[str, Any]) -> dict[str, Any]:
        if "interval" not in data and not data.get("what", "").strip():
            raise serializers.ValidationError({"what": ["give the interval's id or say what."]})
        return data


class BatterySwapInSerializer(serializers.Serializer):
    """The battery put into the RV: its name (a new name makes a battery)."""

    name = StrictCharField(max_length=120)
    notes = StrictCharField(required=False, allow_blank=True, max_length=5000)
