"""The fleet: the device catalog (SDC), ground stations and real vehicles (RVs)."""

from __future__ import annotations

import json
from functools import lru_cache
from typing import Any

from django.conf import settings
from django.core.exceptions import ValidationError
from django.core.validators import MaxValueValidator, MinValueValidator
from django.db import models
from shapely.geometry import Point, Polygon

from fleet.geo import Position
from fleet.kinds import AERIAL, GROUND, KINDS, SURFACE, UNDERWATER, limit_problems
from fleet.sources import SensorSource, SourceError, parse_sources

LAT = [MinValueValidator(-90.0), MaxValueValidator(90.0)]
LNG = [MinValueValidator(-180.0), MaxValueValidator(180.0)]


@lru_cache(maxsize=1024)
def _polygon(area_json: str) -> Polygon:
    # The mapper asks for the areas of the whole fleet at every routing decision; vehicle rows
    # are read anew each time, so the polygons are kept by the area's text.
    return Polygon([(float(lng), float(lat)) for lat, lng in json.loads(area_json)])


def check_ring(area: Any, field: str) -> None:
    """ValidationError on ``field`` unless ``area`` is a closed ring of at least 3 distinct
    ``[lat, lng]`` points that does not cross itself."""
    try:
        ring = [(float(lat), float(lng)) for lat, lng in area]
    except (TypeError, ValueError):
        raise ValidationError({field: "a list of [lat, lng] points"}) from None
    if len(set(ring)) < 3:
        raise ValidationError({field: "needs at least 3 distinct points"})
    if ring[0] != ring[-1]:
        raise ValidationError({field: "must be closed: the last point repeats the first"})
    if not Polygon([(lng, lat) for lat, lng in ring]).is_valid:
        raise ValidationError({field: "is not a valid polygon (does it cross itself?)"})


class SensorKind(models.TextChoices):
    SCALAR = "scalar", "Scalar value"
    GPS = "gps", "GPS fix"
    CAMERA = "camera", "Camera picture"


class SensorType(models.Model):
    """An entry of the system-wide device catalog (SDC): an abstract sensor VVs can ask for."""

    name = models.CharField(max_length=80, unique=True)
    kind = models.CharField(max_length=10, choices=SensorKind.choices)
    unit = models.CharField(max_length=20, blank=True)
    params = models.JSONField(default=dict, blank=True)
    privileged = models.BooleanField(
        default=False, help_text="Only privileged customers' VVs may use it."
    )
    description = models.CharField(max_length=200, blank=True)
    kinds = models.JSONField(
        default=list,
        blank=True,
        help_text='Vehicle kinds that can carry it, e.g. ["underwater", "surface"]; empty: every '
        "kind.",
    )

    class Meta:
        ordering = ["name"]
        verbose_name = "SDC entry"
        verbose_name_plural = "SDC entries"

    def __str__(self) -> str:
        return self.name

    def as_catalog_entry(self) -> dict[str, object]:
        return {"name": self.name, "kind": self.kind, "unit": self.unit, "params": self.params}

    def carried_by(self, kind: str) -> bool:
        """Whether a vehicle of the kind can carry it (an entry naming no kinds: every kind)."""
        return not self.kinds or kind in self.kinds

    def clean(self) -> None:
        super().clean()
        if self.kinds is None:
            self.kinds = []
        if not isinstance(self.kinds, list) or any(k not in KINDS for k in self.kinds):
            raise ValidationError({"kinds": f"a list of vehicle kinds: {', '.join(KINDS)}"})


class GroundStation(models.Model):
    """A ground station: loads new VVs and receives those that end or cannot be served."""

    name = models.CharField(max_length=80, unique=True)
    lat = models.FloatField(validators=LAT)
    lng = models.FloatField(validators=LNG)
    alt = models.FloatField(default=0.0)

    class Meta:
        ordering = ["name"]

    def __str__(self) -> str:
        return self.name

    @property
    def position(self) -> Position:
        return Position(self.lat, self.lng, self.alt)


class VehicleStatus(models.TextChoices):
    ACTIVE = "active", "Active"
    MAINTENANCE = "maintenance", "In maintenance"
    # Gone home to recharge: its worker puts it back into service once it is full.
    CHARGING = "charging", "Recharging"
    # In service, but it cannot be flown (its link is down, its autopilot refused, a pilot
    # took over): its worker puts it back into service when the link returns.
    OFFLINE = "offline", "Offline (link or autopilot)"
    REMOVED = "removed", "Removed"


class VehicleKind(models.TextChoices):
    """How the vehicle moves (``fleet.kinds``): altitude below 0 is depth."""

    AERIAL = AERIAL, "Aerial (copter)"
    GROUND = GROUND, "Ground (rover)"
    SURFACE = SURFACE, "Surface (boat)"
    UNDERWATER = UNDERWATER, "Underwater (sub)"


class Driver(models.TextChoices):
    SIM = "sim", "Simulated"
    MAVLINK = "mavlink", "MAVLink autopilot"


class VehicleCommand(models.TextChoices):
    """What an operator tells an RV to do now, beyond taking it out of service (its worker's
    control loop obeys it once; the RV stays in maintenance until an operator returns it)."""

    RETURN_HOME = "return_home", "Return home now"
    LAND = "land", "Land now"


class Vehicle(models.Model):
    """A real vehicle (RV): where it may fly, how, which sensors it carries, and its state."""

    name = models.CharField(max_length=80, unique=True)
    kind = models.CharField(max_length=10, choices=VehicleKind.choices, default=VehicleKind.AERIAL)
    status = models.CharField(
        max_length=12, choices=VehicleStatus.choices, default=VehicleStatus.ACTIVE
    )
    # Why and when the status changed last (a person's decision or the platform's).
    status_reason = models.CharField(max_length=200, blank=True)
    status_changed = models.DateTimeField(null=True, blank=True)
    # What the vehicle's worker last saw of it (link, battery, armed, mode, fence), and when
    # that changed: health, which never overrides the status a person set.
    health = models.JSONField(default=dict, blank=True)
    health_changed = models.DateTimeField(null=True, blank=True)
    # The last command an operator gave the RV (VehicleCommand), when it was asked, and when
    # the RV's worker took it (null while it waits for the worker; taken exactly once).
    command = models.CharField(max_length=12, choices=VehicleCommand.choices, blank=True)
    command_requested = models.DateTimeField(null=True, blank=True)
    command_taken = models.DateTimeField(null=True, blank=True)
    driver = models.CharField(max_length=10, choices=Driver.choices, default=Driver.SIM)
    driver_url = models.CharField(
        max_length=200, blank=True, help_text="MAVLink connection, e.g. udpin:0.0.0.0:14550."
    )
    depot_lat = models.FloatField(validators=LAT)
    depot_lng = models.FloatField(validators=LNG)
    depot_alt = models.FloatField(default=0.0)
    area = models.JSONField(help_text="Operation area: a closed ring of [lat, lng] points.")
    # Metres above home; below 0 is depth (underwater vehicles). Its kind bounds the range.
    min_altitude_m = models.FloatField(default=0.0)
    max_altitude_m = models.FloatField()
    max_speed_mps = models.FloatField(validators=[MinValueValidator(0.1)])
    climb_rate_mps = models.FloatField(
        default=3.0,
        validators=[MinValueValidator(0.1)],
        help_text="Climb and descent rate; for an underwater vehicle, how fast it rises.",
    )
    dive_rate_mps = models.FloatField(
        null=True,
        blank=True,
        validators=[MinValueValidator(0.1)],
        help_text="Underwater vehicles: how fast it dives; empty: its climb rate.",
    )
    turn_rate_dps = models.FloatField(
        null=True,
        blank=True,
        validators=[MinValueValidator(1.0)],
        help_text="Ground and surface vehicles: how fast it turns, degrees a second; empty: "
        "its kind's default.",
    )
    battery_s = models.FloatField(null=True, blank=True, help_text="Flight endurance, seconds.")
    sensors = models.ManyToManyField(SensorType, related_name="vehicles", blank=True)
    sensor_sources = models.JSONField(
        default=dict,
        blank=True,
        help_text='Where its sensors\' readings come from, by SDC entry name, e.g. {"CO2": '
        '{"source": "named_value", "name": "CO2"}}; sources: field (simulated), telemetry, '
        "named_value, camera (MAVLink), plugin (its own computer). A sensor not named here reads the "
        "simulated field.",
    )
    # Live state, written by the vehicle's control loop.
    lat = models.FloatField(null=True, blank=True)
    lng = models.FloatField(null=True, blank=True)
    alt = models.FloatField(null=True, blank=True)
    phase = models.CharField(max_length=12, default="landed")
    distance_m = models.FloatField(default=0.0)
    flight_s = models.FloatField(default=0.0)
    tasks_done = models.PositiveIntegerField(default=0)
    planner_state = models.JSONField(default=dict, blank=True)
    worker_seen = models.DateTimeField(
        null=True, blank=True, help_text="When the vehicle's worker last reported."
    )
    updated = models.DateTimeField(auto_now=True)
    # Who may fly it (staff in the "pilot" group), and who is its pilot in command now: one of
    # them who took it on duty (``vehicle_take_duty``). With CPCC_REQUIRE_PILOT an RV with no
    # pilot on duty takes no new work.
    pilots = models.ManyToManyField(
        settings.AUTH_USER_MODEL,
        blank=True,
        related_name="piloted_vehicles",
        help_text="The pilots who may operate this RV and take it on duty.",
    )
    pilot_on_duty = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="vehicles_on_duty",
        help_text="Its pilot in command now (a pilot takes it on duty and hands it over).",
    )

    class Meta:
        ordering = ["name"]
        permissions = [
            ("operate_vehicle", "Can operate an RV: maintenance, return home, land, return"),
        ]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(max_altitude_m__gte=models.F("min_altitude_m")),
                name="vehicle_altitude_range",
            ),
            models.CheckConstraint(
                condition=models.Q(max_speed_mps__gt=0), name="vehicle_speed_positive"
            ),
        ]

    def __str__(self) -> str:
        return self.name

    def get_additional_data(self) -> dict[str, Any]:
        """What the audit log keeps with every change of the RV (django-auditlog): its pilot
        in command then."""
        pilot = self.pilot_on_duty
        return {"pilot_in_command": pilot.get_username() if pilot is not None else None}

    @property
    def depot(self) -> Position:
        return Position(self.depot_lat, self.depot_lng, self.depot_alt)

    @property
    def position(self) -> Position:
        if self.lat is None or self.lng is None:
            return self.depot
        return Position(self.lat, self.lng, self.alt or 0.0)

    @property
    def area_polygon(self) -> Polygon:
        """The operation area as a shapely polygon in (lng, lat) coordinates."""
        return _polygon(json.dumps(self.area))

    def covers(self, position: Position) -> bool:
        """Whether a position lies in the operation area (its border included)."""
        return bool(self.area_polygon.covers(Point(position.lng, position.lat)))

    def clean(self) -> None:
        super().clean()
        check_ring(self.area, "area")
        if None not in (self.min_altitude_m, self.max_altitude_m, self.max_speed_mps):
            problems = limit_problems(
                self.kind,
                min_altitude_m=self.min_altitude_m,
                max_altitude_m=self.max_altitude_m,
                max_speed_mps=self.max_speed_mps,
                depot_alt_m=self.depot_alt or 0.0,
            )
            if self.dive_rate_mps is not None and self.kind != UNDERWATER:
                problems["dive_rate_mps"] = "only an underwater vehicle dives"
            if self.turn_rate_dps is not None and self.kind not in (GROUND, SURFACE):
                problems["turn_rate_dps"] = "only ground and surface vehicles turn in place"
            if problems:
                raise ValidationError(problems)
        if self.sensor_sources is None:  # an empty field in a form: no sources named
            self.sensor_sources = {}
        try:
            self.parsed_sources()
        except SourceError as exc:
            raise ValidationError({"sensor_sources": str(exc)}) from None

    def parsed_sources(self) -> dict[str, SensorSource]:
        """Its sensor sources, checked against the SDC (SourceError says what is wrong)."""
        catalog = {s.name: s.as_catalog_entry() for s in SensorType.objects.all()}
        return parse_sources(
            self.sensor_sources, catalog=catalog, mavlink=self.driver == Driver.MAVLINK
        )


class NoFlyZone(models.Model):
    """An exclusion zone the provider draws (an airport, a prison, a crowd): no RV serves a
    point inside it between its altitudes, and each RV's autopilot gets it as an exclusion
    fence."""

    name = models.CharField(max_length=80, unique=True)
    area = models.JSONField(help_text="A closed ring of [lat, lng] points.")
    min_altitude_m = models.FloatField(
        default=0.0, validators=[MinValueValidator(0.0)], help_text="Metres above ground."
    )
    max_altitude_m = models.FloatField(
        null=True, blank=True, help_text="Metres above ground; empty: no ceiling."
    )
    updated = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["name"]
        verbose_name = "no-fly zone"

    def __str__(self) -> str:
        return self.name

    @property
    def area_polygon(self) -> Polygon:
        return _polygon(json.dumps(self.area))

    def clean(self) -> None:
        super().clean()
        check_ring(self.area, "area")
        if self.max_altitude_m is not None and self.max_altitude_m < self.min_altitude_m:
            raise ValidationError(
                {"max_altitude_m": f"must not be below min_altitude_m ({self.min_altitude_m:g} m)"}
            )


class RallyPoint(models.Model):
    """A place where an RV may land or wait instead of its home (ArduPilot's rally points),
    given to every RV's autopilot."""

    name = models.CharField(max_length=80, unique=True)
    lat = models.FloatField(validators=LAT)
    lng = models.FloatField(validators=LNG)
    alt = models.FloatField(default=20.0, help_text="Metres above ground it holds at.")
    updated = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["name"]

    def __str__(self) -> str:
        return self.name

    @property
    def position(self) -> Position:
        return Position(self.lat, self.lng, self.alt)


class PilotDuty(models.Model):
    """A pilot's time in command of an RV: from taking it on duty to handing it over."""

    vehicle = models.ForeignKey(Vehicle, on_delete=models.CASCADE, related_name="duties")
    pilot = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, on_delete=models.SET_NULL, related_name="duties"
    )
    # Kept as it was: the record outlives a pilot's account.
    pilot_name = models.CharField(max_length=150)
    started = models.DateTimeField()
    ended = models.DateTimeField(null=True, blank=True)
    handed_to = models.CharField(max_length=150, blank=True)

    class Meta:
        ordering = ["-started", "-id"]
        verbose_name_plural = "pilot duties"
        indexes = [models.Index(fields=["vehicle", "ended"])]

    def __str__(self) -> str:
        return f"{self.pilot_name} on {self.vehicle}"


class TakeOff(models.Model):
    """One take-off of an RV, with its pilot in command then (empty: none on duty)."""

    vehicle = models.ForeignKey(Vehicle, on_delete=models.CASCADE, related_name="take_offs")
    at = models.DateTimeField()
    at_s = models.FloatField(help_text="Platform clock.")
    pilot = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    pilot_name = models.CharField(max_length=150, blank=True)

    class Meta:
        ordering = ["-at", "-id"]
        verbose_name = "take-off"
        indexes = [models.Index(fields=["vehicle", "-at"])]

    def __str__(self) -> str:
        return f"{self.vehicle} at {self.at:%Y-%m-%d %H:%M:%S}"
