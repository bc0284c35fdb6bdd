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


class FlightEnd(models.TextChoices):
    """How a flight ended."""

    LANDED_HOME = "landed_home", "Landed at home"
    LANDED_ELSEWHERE = "landed_elsewhere", "Landed elsewhere"
    LINK_LOST = "link_lost", "Link lost"
    FAILSAFE = "failsafe", "Failsafe (the autopilot took over)"
    OPERATOR = "operator", "An operator's command"


class Flight(models.Model):
    """One flight of an RV, from its take-off to its landing (open while it flies), written
    by its control loop with its reports: who was its pilot in command, how long and how far
    it flew, how high, its battery then, the tasks it served and how it ended."""

    vehicle = models.ForeignKey(Vehicle, on_delete=models.CASCADE, related_name="flights")
    pilot = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    # Kept as it was at the take-off: the record outlives a pilot's account.
    pilot_name = models.CharField(max_length=150, blank=True)
    started = models.DateTimeField()
    started_s = models.FloatField(help_text="Platform clock.")
    ended = models.DateTimeField(null=True, blank=True)
    ended_s = models.FloatField(null=True, blank=True, help_text="Platform clock.")
    ended_how = models.CharField(max_length=20, choices=FlightEnd.choices, blank=True)
    # The vehicle's odometers at the take-off: the flight's distance and time are what they
    # gained until the landing.
    odometer_start_m = models.FloatField(default=0.0)
    flight_s_start = models.FloatField(default=0.0)
    duration_s = models.FloatField(null=True, blank=True)
    distance_m = models.FloatField(null=True, blank=True)
    max_alt_m = models.FloatField(null=True, blank=True, help_text="Highest, above home.")
    battery_start_pct = models.FloatField(null=True, blank=True)
    battery_end_pct = models.FloatField(null=True, blank=True)
    battery_name = models.CharField(
        max_length=120, blank=True, help_text="The battery flown (the autopilot's id or serial)."
    )
    tasks_served = models.PositiveIntegerField(default=0)
    # [{"id", "name"}] of the customers whose tasks it served (staff data).
    customers = models.JSONField(default=list, blank=True)
    vvs = models.JSONField(default=list, blank=True, help_text="The VVs aboard: [{id, name}].")
    # Where it flew: [t_s, lat, lng, alt, battery_pct or null] at each report of its loop (the
    # ends of its legs and where it stopped), for the flight's page and a simulated RV's log.
    track = models.JSONField(default=list, blank=True)
    log = models.FileField(upload_to="flights/", blank=True)

    class Meta:
        ordering = ["-started", "-id"]
        indexes = [
            models.Index(fields=["vehicle", "-started"], name="flight_vehicle_started"),
            models.Index(fields=["started"], name="flight_started"),
        ]

    def __str__(self) -> str:
        return f"{self.vehicle} at {self.started:%Y-%m-%d %H:%M:%S}"


# The battery cycle rule (``fleet.maintenance.cycle_step``): a charge from below CYCLE_LOW_PCT
# to above CYCLE_FULL_PCT counts one cycle.
CYCLE_LOW_PCT = 50.0
CYCLE_FULL_PCT = 90.0
CYCLE_RULE = (
    "A charge from below 50 % to above 90 % counts one cycle: a battery seen below 50 % and "
    "later above 90 % counts one, then it must go below 50 % again. A swap that shows a full "
    "battery after a low one (the same battery, charged) counts one too."
)


class Battery(models.Model):
    """A battery pack and its logbook: the RV it is in now, its cycles (CYCLE_RULE), flights,
    flight hours and lowest charge seen, and whether it is retired. Identified by the
    autopilot's serial (SMART_BATTERY_INFO) or battery id (BATTERY_STATUS.id) where it reports
    one, else named by the operator when it is swapped."""

    name = models.CharField(max_length=120, unique=True)
    serial = models.CharField(
        max_length=120, blank=True, help_text="The autopilot's serial of it, where it reports one."
    )
    autopilot_id = models.PositiveSmallIntegerField(
        null=True, blank=True, help_text="The autopilot's battery id (BATTERY_STATUS.id)."
    )
    vehicle = models.ForeignKey(
        Vehicle,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="batteries",
        help_text="The RV it is in now (empty: in none).",
    )
    installed = models.DateTimeField(null=True, blank=True, help_text="Put into its RV then.")
    cycles = models.PositiveIntegerField(default=0, help_text=CYCLE_RULE)
    # The cycle rule's memory: seen below CYCLE_LOW_PCT since it last counted a cycle.
    below_low = models.BooleanField(default=False)
    lowest_pct = models.FloatField(null=True, blank=True, help_text="The lowest charge seen, %.")
    flights = models.PositiveIntegerField(default=0)
    flight_s = models.FloatField(default=0.0, help_text="Flight time, seconds.")
    # The flights of its RVs that ended up to then are counted in flights and flight_s.
    counted_until = models.DateTimeField(null=True, blank=True)
    retired = models.DateTimeField(
        null=True, blank=True, help_text="Retired then (past its retirement cycles): not flown."
    )
    created = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ["name"]
        verbose_name_plural = "batteries"
        permissions = [("swap_battery", "Can record a battery swap on an RV")]
        constraints = [
            # One battery in an RV at a time: another one seen is a swap.
            models.UniqueConstraint(
                fields=["vehicle"],
                condition=models.Q(vehicle__isnull=False),
                name="battery_one_per_vehicle",
            ),
            models.UniqueConstraint(
                fields=["serial"], condition=~models.Q(serial=""), name="battery_serial_unique"
            ),
        ]

    def __str__(self) -> str:
        return self.name


class MaintenanceInterval(models.Model):
    """A maintenance interval ("25-hour inspection"): for the RVs of a kind, one RV, or every
    RV (neither given), due every so many flight hours, flights or days; for their batteries,
    every so many cycles, and a battery retires at so many cycles. Due soon at 90 % of a
    limit; overdue (the RV is grounded) at 100 % until someone records the maintenance."""

    name = models.CharField(max_length=80)
    kind = models.CharField(
        max_length=10,
        choices=VehicleKind.choices,
        blank=True,
        help_text="The RVs of this kind; empty (and no vehicle): every RV.",
    )
    vehicle = models.ForeignKey(
        Vehicle,
        null=True,
        blank=True,
        on_delete=models.CASCADE,
        related_name="maintenance_intervals",
        help_text="Only this RV (then no kind).",
    )
    every_hours = models.FloatField(
        null=True, blank=True, validators=[MinValueValidator(0.01)], help_text="Flight hours."
    )
    every_flights = models.PositiveIntegerField(
        null=True, blank=True, validators=[MinValueValidator(1)]
    )
    every_days = models.PositiveIntegerField(
        null=True, blank=True, validators=[MinValueValidator(1)]
    )
    every_cycles = models.PositiveIntegerField(
        null=True, blank=True, validators=[MinValueValidator(1)], help_text="Battery cycles."
    )
    retire_cycles = models.PositiveIntegerField(
        null=True,
        blank=True,
        validators=[MinValueValidator(1)],
        help_text="A battery retires at this many cycles: its RV is grounded until it is swapped.",
    )
    created = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ["name", "pk"]
        constraints = [
            models.CheckConstraint(
                condition=~(models.Q(vehicle__isnull=False) & ~models.Q(kind="")),
                name="interval_kind_or_vehicle",
            ),
            models.CheckConstraint(
                condition=models.Q(every_hours__isnull=False)
                | models.Q(every_flights__isnull=False)
                | models.Q(every_days__isnull=False)
                | models.Q(every_cycles__isnull=False)
                | models.Q(retire_cycles__isnull=False),
                name="interval_has_a_limit",
            ),
            models.CheckConstraint(
                condition=models.Q(every_hours__isnull=True) | models.Q(every_hours__gt=0),
                name="interval_hours_positive",
            ),
        ]

    def __str__(self) -> str:
        return self.name

    def clean(self) -> None:
        super().clean()
        if self.vehicle_id is not None and self.kind:
            raise ValidationError({"kind": "an interval is for a kind or for one vehicle"})
        limits = (
            self.every_hours,
            self.every_flights,
            self.every_days,
            self.every_cycles,
            self.retire_cycles,
        )
        if all(limit is None for limit in limits):
            raise ValidationError("give at least one limit: hours, flights, days or cycles")


class MaintenanceRecord(models.Model):
    """Maintenance a person did (or a battery swap they recorded), on an RV or a battery: who,
    what (an interval, or free text), when and notes. Recording an interval's maintenance
    starts it again."""

    vehicle = models.ForeignKey(
        Vehicle,
        null=True,
        blank=True,
        on_delete=models.CASCADE,
        related_name="maintenance_records",
    )
    battery = models.ForeignKey(
        Battery,
        null=True,
        blank=True,
        on_delete=models.CASCADE,
        related_name="maintenance_records",
    )
    interval = models.ForeignKey(
        MaintenanceInterval,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="records",
    )
    what = models.CharField(max_length=200)
    by = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    # Kept as it was: the record outlives a person's account.
    by_name = models.CharField(max_length=150)
    at = models.DateTimeField()
    notes = models.TextField(blank=True)
    # The battery's cycles then: its cycle intervals count from them.
    battery_cycles = models.PositiveIntegerField(null=True, blank=True)

    class Meta:
        ordering = ["-at", "-id"]
        indexes = [models.Index(fields=["vehicle", "interval", "-at"], name="maint_vehicle_at")]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(vehicle__isnull=False) | models.Q(battery__isnull=False),
                name="maint_record_has_subject",
            )
        ]

    def __str__(self) -> str:
        return f"{self.what} by {self.by_name} at {self.at:%Y-%m-%d %H:%M}"
