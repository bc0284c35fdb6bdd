from datetime import datetime
from typing import Any

from django import forms
from django.conf import settings
from django.contrib import admin, messages
from django.contrib.auth import get_user_model
from django.core.exceptions import PermissionDenied
from django.db.models import Q, QuerySet
from django.http import (
    HttpRequest,
    HttpResponse,
    HttpResponseBadRequest,
    HttpResponseNotAllowed,
    HttpResponseRedirect,
)
from django.shortcuts import get_object_or_404
from django.template.response import TemplateResponse
from django.urls import URLPattern, path, reverse
from django.utils import timezone
from django.utils.html import format_html

from accounts.roles import PILOT
from cpcc_site.admin_display import METRES, SPEED, PositionShown, duration, rounded
from cpcc_site.admin_site import ExplainedWhenEmpty
from fleet.maintenance import (
    Due,
    MaintenanceDue,
    battery_due_list,
    fleet_maintenance,
    intervals_for,
    vehicle_batteries,
    vehicle_maintenance,
)
from fleet.models import (
    CYCLE_RULE,
    Battery,
    Driver,
    Flight,
    GroundStation,
    MaintenanceInterval,
    MaintenanceRecord,
    NoFlyZone,
    PilotDuty,
    RallyPoint,
    SensorType,
    Vehicle,
    VehicleCommand,
    VehicleKind,
    VehicleStatus,
)
from fleet.selectors import (
    flight_list,
    ground_station_list,
    sensor_carriers,
    sensors_not_carried,
    vehicle_list,
    vehicle_logbook,
)
from fleet.widgets import AreaWidget, map_media
from missions.selectors import flight_tasks, with_active_vv_count
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    DutyRefused,
    GroundStationConfig,
    VehicleConfig,
    VehicleRemoved,
    battery_swap,
    ground_station_create,
    ground_station_update,
    maintenance_record,
    no_fly_zone_delete,
    no_fly_zone_save,
    rally_point_delete,
    rally_point_save,
    vehicle_command,
    vehicle_create,
    vehicle_hand_over,
    vehicle_set_status,
    vehicle_take_duty,
    vehicle_update,
    vehicles_check_maintenance,
)
from vvm_worker.services.flight_logs import flight_log_kept


def _config(form: Any, fields: Any, only_changed: bool) -> Any:
    """The form's values of a service's config fields (those the user changed, on an edit)."""
    names = form.changed_data if only_changed else form.cleaned_data
    return {f: form.cleaned_data[f] for f in names if f in fields.__annotations__}


def _station(station: GroundStation) -> dict[str, Any]:
    return {"name": station.name, "lat": station.lat, "lng": station.lng}


def _area_widget(*, besides: int | None = None) -> AreaWidget:
    """An area's map, with the areas of the RVs in the fleet (but ``besides``) and the ground
    stations around it."""
    others = [
        {"name": v.name, "status": v.status, "area": v.area}
        for v in vehicle_list()
        if v.status != VehicleStatus.REMOVED and v.pk != besides
    ]
    return AreaWidget(others=others, stations=[_station(gs) for gs in ground_station_list()])


def _age(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s ago"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min ago"
    if seconds < 172800:
        return f"{seconds / 3600:.0f} h ago"
    return f"{seconds / 86400:.0f} days ago"


def _health_text(health: dict[str, Any]) -> str:
    """A vehicle's health in a few words: "link up · armed · GUIDED · fence loaded"."""
    parts = []
    if health.get("worker"):
        parts.append(f"worker {health['worker']}")
    if health.get("link"):
        parts.append(f"link {health['link']}")
    if health.get("armed") is not None:
        parts.append("armed" if health["armed"] else "disarmed")
    if health.get("mode"):
        parts.append(str(health["mode"]))
    if health.get("fence"):
        parts.append(f"fence {health['fence']}")
    if health.get("took_over"):
        parts.append(f"taken over in {health['took_over']}")
    return " · ".join(parts)


def _battery(vehicle: Vehicle, health: dict[str, Any]) -> tuple[int | None, str]:
    """The RV's battery in percent as last known, or None and why there is none."""
    if health.get("battery_pct") is not None:
        return round(health["battery_pct"]), ""
    if vehicle.driver == Driver.MAVLINK:
        if vehicle.worker_seen is None:
            return None, "its worker has not reported yet"
        return None, "the autopilot has not reported its battery"
    if vehicle.battery_s:
        # What the simulated vehicle's battery reports: endurance less the time flown.
        return round(100 * max(0.0, 1 - vehicle.flight_s / vehicle.battery_s)), ""
    return None, "simulated without a battery (no battery_s set)"


# What an operator may do with an RV on the fleet overview: its button, the question the
# confirmation asks, and the statuses in which it makes no sense. (Who may do which:
# ``_acts_allowed``.)
FLEET_ACTIONS: dict[str, tuple[str, str, frozenset[str]]] = {
    "maintenance": (
        "Maintenance",
        "Put {name} into maintenance? Its VVs move to other RVs; it flies home, lands and "
        "takes no work until it is returned to service.",
        frozenset({VehicleStatus.MAINTENANCE, VehicleStatus.REMOVED}),
    ),
    "return": (
        "Return to service",
        "Return {name} to service? It takes work at once.",
        frozenset({VehicleStatus.ACTIVE, VehicleStatus.REMOVED}),
    ),
    VehicleCommand.RETURN_HOME: (
        "Return home now",
        "Send {name} home now? It goes into maintenance (its VVs move to other RVs), flies "
        "home and lands, and stays there until it is returned to service.",
        frozenset({VehicleStatus.REMOVED}),
    ),
    VehicleCommand.LAND: (
        "Land now",
        "Land {name} now, where it is? It goes into maintenance (its VVs move to other RVs) "
        "and lands on the spot, and stays there until it is returned to service.",
        frozenset({VehicleStatus.REMOVED}),
    ),
    "take_duty": (
        "Take on duty",
        "Take {name} on duty? You become its pilot in command: recorded with each of its "
        "take-offs and in the audit log with every command, until you hand it over.",
        frozenset({VehicleStatus.REMOVED}),
    ),
    "hand_over": (
        "Hand over",
        "Hand {name} over to {to}? {after}",
        frozenset({VehicleStatus.REMOVED}),
    ),
}
# The acts that operate an RV: its pilots', and those of any staff who may change vehicles.
OPERATOR_ACTS = ("maintenance", "return", VehicleCommand.RETURN_HOME, VehicleCommand.LAND)
NOBODY = "nobody"


# Whom a hand-over goes to where the page's form says it (the button's question).
CHOSEN = "the pilot chosen beside the button (or nobody)"


def _confirm(vehicle: Vehicle, act: str, to: Any = CHOSEN) -> str:
    """The question an act asks about the RV; for a hand-over, ``to`` is the pilot it goes
    to, None for nobody, or CHOSEN while the form has not said."""
    _, confirm, _ = FLEET_ACTIONS[act]
    if act != "hand_over":
        return confirm.format(name=vehicle.name)
    if to is None or to == CHOSEN:
        whom = NOBODY if to is None else CHOSEN
        then = "takes no new work" if settings.CPCC_REQUIRE_PILOT else "has no pilot in command"
        after = f"With nobody, it {then} until a pilot takes it on duty."
    else:
        whom = to.get_username()
        after = f"{whom} becomes its pilot in command."
    return confirm.format(name=vehicle.name, to=whom, after=after)


def _acts_allowed(user: Any, vehicle: Vehicle) -> list[str]:
    """What the user may do with the RV on the fleet overview: staff who may change vehicles
    operate any RV, a pilot (``fleet.operate_vehicle``) those they are assigned; one of its
    pilots (or a superuser) takes it on duty while nobody is; its pilot in command, or staff
    who may change vehicles, hands it over (to nobody, or to another of its pilots). (The
    RV's ``pilots`` prefetched, its pilot on duty read with it.)"""
    manager = user.has_perm("fleet.change_vehicle")
    assigned = any(p.pk == user.pk for p in vehicle.pilots.all())
    if not manager and not (assigned and user.has_perm("fleet.operate_vehicle")):
        return []
    acts: list[str] = [str(act) for act in OPERATOR_ACTS]
    on_duty = vehicle.pilot_on_duty_id
    if on_duty is None and (assigned or user.is_superuser):
        acts.append("take_duty")
    if (on_duty is not None and on_duty == user.pk) or (
        manager and (on_duty is not None or _others(vehicle))
    ):
        acts.append("hand_over")
    return acts


def _others(vehicle: Vehicle) -> list[Any]:
    """The RV's pilots but the one on duty: those it may be handed over to."""
    return [p for p in vehicle.pilots.all() if p.pk != vehicle.pilot_on_duty_id]


def _actions(vehicle: Vehicle, acts: list[str]) -> list[dict[str, Any]]:
    """The RV's buttons on the fleet overview, those of ``acts`` (``never``: the statuses that
    disable one, for the page to follow the status live; ``to``: whom a hand-over may go to,
    nobody first)."""
    return [
        {
            "name": str(name),
            "label": label,
            "confirm": _confirm(vehicle, str(name)),
            "disabled": vehicle.status in never,
            "never": " ".join(sorted(never)),
            "to": [{"value": "", "name": NOBODY}]
            + [{"value": p.pk, "name": p.get_username()} for p in _others(vehicle)]
            if name == "hand_over"
            else [],
        }
        for name, (label, _, never) in FLEET_ACTIONS.items()
        if name in acts
    ]


def _command(vehicle: Vehicle) -> dict[str, Any] | None:
    """The operator's last command for the RV, when it was asked and taken by its worker."""
    if not vehicle.command or vehicle.command_requested is None:
        return None
    return {
        "label": VehicleCommand(vehicle.command).label,
        "asked": vehicle.command_requested,
        "asked_iso": vehicle.command_requested.isoformat(),
        "taken": vehicle.command_taken,
    }


_DUE_UNITS = {"hours": "flight hours", "flights": "flights", "days": "days", "cycles": "cycles"}


def _due_text(due: Due) -> str:
    """ "25-hour inspection: 23.5 of 25 flight hours" (a battery's: its name too)."""
    battery = f" (battery {due.battery})" if due.battery else ""
    return f"{due.name}{battery}: {due.used:g} of {due.limit:g} {_DUE_UNITS[due.kind]}"


def _maintenance_shown(due: MaintenanceDue | None) -> dict[str, list[str]]:
    if due is None:
        return {"due_soon": [], "overdue": []}
    return {
        "due_soon": [_due_text(d) for d in due.due_soon],
        "overdue": [_due_text(d) for d in due.overdue],
    }


def _overview_row(
    vehicle: Any, now: datetime, lease_s: float, user: Any, due: MaintenanceDue | None = None
) -> dict[str, Any]:
    """What the fleet overview shows of an RV (annotated with ``vvs_aboard``) to ``user``
    (the actions they may do), with its maintenance due soon and overdue (``due``). Its
    worker's reports keep the page live (static/js/admin/fleet-overview.js); its speed and
    next task are known from them only."""
    if vehicle.worker_seen is None:
        lease, lease_text = "never", "never reported"
    else:
        age_s = max(0.0, (now - vehicle.worker_seen).total_seconds())
        lease = "fresh" if age_s < lease_s else "expired"
        lease_text = f"{lease}, {_age(age_s)}"
    health = vehicle.health or {}
    battery, battery_why = _battery(vehicle, health)
    position = vehicle.position
    link = health.get("link") or ("worker stopped" if health.get("worker") else "not reported")
    return {
        "id": vehicle.pk,
        "name": vehicle.name,
        "kind": vehicle.kind,
        "kind_label": vehicle.get_kind_display(),
        "url": reverse("admin:fleet_vehicle_change", args=[vehicle.pk]),
        "act_url": reverse("admin:fleet_vehicle_act", args=[vehicle.pk]),
        "driver": vehicle.get_driver_display(),
        "status": vehicle.status,
        "status_label": vehicle.get_status_display(),
        "status_reason": vehicle.status_reason,
        "status_changed": vehicle.status_changed,
        "health": _health_text(health),
        "health_changed": vehicle.health_changed,
        "link": link,
        "phase": vehicle.phase,
        "lat": position.lat,
        "lng": position.lng,
        "alt": position.alt,
        "reported": vehicle.lat is not None,
        "battery": battery,
        "battery_why": battery_why,
        "tasks_done": vehicle.tasks_done,
        "vvs_aboard": vehicle.vvs_aboard,
        "lease": lease,
        "lease_text": lease_text,
        "area": vehicle.area,
        "command": _command(vehicle),
        "pilot_on_duty": pilot.get_username() if (pilot := vehicle.pilot_on_duty) else "",
        "actions": _actions(vehicle, _acts_allowed(user, vehicle)),
        "maintenance": _maintenance_shown(due),
    }


# What the page's table shows and its map's data leaves out.
_NOT_FOR_THE_MAP = (
    "actions",
    "command",
    "status_changed",
    "health_changed",
    "pilot_on_duty",
    "maintenance",
)


class SensorTypeForm(forms.ModelForm):
    """An SDC entry, with the vehicle kinds that can carry it as checkboxes; it may not leave
    out the kind of an RV that carries it."""

    kinds = forms.MultipleChoiceField(
        choices=VehicleKind.choices,
        widget=forms.CheckboxSelectMultiple,
        required=False,
        help_text="The vehicle kinds that can carry it; none ticked: every kind.",
    )

    class Meta:
        model = SensorType
        fields = ["name", "kind", "unit", "params", "privileged", "description", "kinds"]

    def clean_kinds(self) -> list[str]:
        kinds = [kind for kind in VehicleKind.values if kind in self.cleaned_data["kinds"]]
        if kinds and self.instance.pk is not None:
            left_out = [
                f"{v.name} ({v.kind})"
                for v in sensor_carriers(sensor=self.instance)
                if v.kind not in kinds
            ]
            if left_out:
                raise forms.ValidationError(
                    f"carried by {', '.join(left_out)}: tick their kind too, or take the sensor "
                    "off them first"
                )
        return kinds


@admin.register(SensorType)
class SensorTypeAdmin(ExplainedWhenEmpty):
    form = SensorTypeForm
    empty_list_help = (
        "An SDC entry is a sensor VVs ask for by name (VV.sensor.get('CO2')): its kind, its "
        "unit, and which kinds of RV carry it. Add one, then tick it on the RVs that carry it."
    )
    list_display = ["name", "kind", "unit", "privileged", "kinds_shown"]
    list_filter = ["kind", "privileged"]
    search_fields = ["name"]

    @admin.display(description="carried by")
    def kinds_shown(self, sensor: SensorType) -> str:
        return ", ".join(sensor.kinds) or "every kind"


@admin.register(GroundStation)
class GroundStationAdmin(PositionShown, ExplainedWhenEmpty):
    """Ground stations; a new one starts the VVs that waited for one."""

    empty_list_help = (
        "A ground station loads customers' new VVs and keeps those that wait for an RV, have "
        "ended or cannot be served; no VV starts before there is one. Add one with its "
        "position."
    )
    list_display = ["name", "lat_shown", "lng_shown", "alt_shown"]
    search_fields = ["name"]

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        if change:
            config = _config(form, GroundStationConfig, only_changed=True)
            ground_station_update(station=obj, config=config)
        else:
            config = _config(form, GroundStationConfig, only_changed=False)
            obj.pk = ground_station_create(config=config, vvm=platform_vvm()).pk


class _AirspaceAdmin(ExplainedWhenEmpty):
    """Saved and deleted through its services, which tell every RV's worker."""

    def _save(self, obj: Any) -> None:
        raise NotImplementedError

    def _delete(self, obj: Any) -> None:
        raise NotImplementedError

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        self._save(obj)

    def delete_model(self, request: HttpRequest, obj: Any) -> None:
        self._delete(obj)

    def delete_queryset(self, request: HttpRequest, queryset: QuerySet[Any]) -> None:
        for obj in queryset:
            self._delete(obj)


@admin.register(NoFlyZone)
class NoFlyZoneAdmin(_AirspaceAdmin):
    """No-fly zones: no RV serves a task inside one (between its altitudes), and every RV's
    autopilot gets it as an exclusion fence (when it holds at every altitude the RV flies)."""

    empty_list_help = (
        "A no-fly zone is an area no RV flies into between its altitudes (an airport, a "
        "prison, a crowd): no task inside it is served, and every RV's autopilot gets it as a "
        "fence. Add one by drawing it on the map."
    )
    list_display = ["name", "min_altitude_shown", "max_altitude_shown", "updated"]
    min_altitude_shown = rounded(
        "min_altitude_m", digits=METRES, unit="m", description="min altitude"
    )
    max_altitude_shown = rounded(
        "max_altitude_m", digits=METRES, unit="m", description="max altitude"
    )
    search_fields = ["name"]
    fields = ["name", "area", ("min_altitude_m", "max_altitude_m")]

    def get_form(
        self, request: HttpRequest, obj: Any = None, change: bool = False, **kwargs: Any
    ) -> Any:
        # The zone on a map, with the RVs' areas and the ground stations around it.
        kwargs["widgets"] = {**kwargs.get("widgets", {}), "area": _area_widget()}
        return super().get_form(request, obj, change=change, **kwargs)

    def _save(self, obj: Any) -> None:
        no_fly_zone_save(zone=obj, vvm=platform_vvm())

    def _delete(self, obj: Any) -> None:
        no_fly_zone_delete(zone=obj, vvm=platform_vvm())


@admin.register(RallyPoint)
class RallyPointAdmin(PositionShown, _AirspaceAdmin):
    """Rally points every RV's autopilot gets (where it may land or wait instead of home)."""

    empty_list_help = (
        "A rally point is a place where an RV may land or wait instead of flying home (the "
        "autopilot's rally points); every RV's autopilot gets them all. Add one with its "
        "position and the altitude it holds at."
    )
    list_display = ["name", "lat_shown", "lng_shown", "alt_shown"]
    search_fields = ["name"]

    def _save(self, obj: Any) -> None:
        rally_point_save(point=obj, vvm=platform_vvm())

    def _delete(self, obj: Any) -> None:
        rally_point_delete(point=obj, vvm=platform_vvm())


class VehicleForm(forms.ModelForm):
    """An RV's configuration; its kind's limits are the model's (``Vehicle.clean``), and a
    sensor its kind cannot carry is an error naming the sensor."""

    class Meta:
        model = Vehicle
        fields = ["kind", "sensors"]  # the admin gives it its fieldsets' fields

    def clean(self) -> dict[str, Any]:
        cleaned: dict[str, Any] = super().clean() or {}
        kind, sensors = cleaned.get("kind"), cleaned.get("sensors")
        if kind and sensors is not None:
            problem = sensors_not_carried(kind=kind, sensors=sensors)
            if problem is not None:
                raise forms.ValidationError(problem)
        return cleaned


@admin.register(Vehicle)
class VehicleAdmin(PositionShown, ExplainedWhenEmpty):
    """RVs: their kind, limits and sensors; status changes go through the actions, which move
    the VVs aboard an RV that leaves service to RVs that can serve them."""

    empty_list_help = (
        "An RV (real vehicle) is a copter, rover, boat or sub of the fleet: where it may fly, "
        "how fast, which sensors it carries, whether it is simulated or flown over MAVLink. VVs "
        "fly aboard the RVs whose area and sensors fit their tasks. Add one with its area drawn "
        "on the map; it takes work at once."
    )
    form = VehicleForm
    list_display = [
        "name",
        "kind",
        "status",
        "driver",
        "max_speed_shown",
        "phase",
        "tasks_done",
        "worker_seen",
        "logbook_link",
    ]
    list_filter = ["status", "kind", "driver"]
    search_fields = ["name"]
    filter_horizontal = ["sensors", "pilots"]
    readonly_fields = [
        "pilot_on_duty",
        "status",
        "status_reason",
        "status_changed",
        "health",
        "health_changed",
        "lat_shown",
        "lng_shown",
        "alt_shown",
        "phase",
        "distance_shown",
        "flight_shown",
        "tasks_done",
        "worker_seen",
    ]
    # The floats of its state and speed as what they mean (cpcc_site/admin_display.py).
    max_speed_shown = rounded("max_speed_mps", digits=SPEED, unit="m/s", description="max speed")
    distance_shown = rounded("distance_m", digits=METRES, unit="m", description="distance flown")
    flight_shown = duration("flight_s", description="flight time")
    actions = ["put_into_maintenance", "return_to_service", "remove_from_fleet"]
    fieldsets = [
        (
            None,
            {
                "fields": [
                    "name",
                    "kind",
                    ("status", "status_reason", "status_changed"),
                    "driver",
                    "driver_url",
                ]
            },
        ),
        ("Health", {"fields": ["health", "health_changed"]}),
        (
            "Pilots",
            {
                "fields": ["pilots", "pilot_on_duty"],
                "description": "Staff of the pilot group who may operate this RV and take it "
                "on duty; its pilot in command is the one on duty (the fleet overview's "
                "Take on duty and Hand over).",
            },
        ),
        (
            "Limits",
            {
                "fields": [
                    ("depot_lat", "depot_lng", "depot_alt"),
                    "area",
                    ("min_altitude_m", "max_altitude_m"),
                    ("max_speed_mps", "climb_rate_mps"),
                    ("dive_rate_mps", "turn_rate_dps"),
                    "battery_s",
                    "sensors",
                    "sensor_sources",
                ]
            },
        ),
        (
            "State",
            {
                "fields": [
                    "phase",
                    ("lat_shown", "lng_shown", "alt_shown"),
                    "distance_shown",
                    "flight_shown",
                    "tasks_done",
                    "worker_seen",
                ]
            },
        ),
    ]

    def get_form(
        self, request: HttpRequest, obj: Any = None, change: bool = False, **kwargs: Any
    ) -> Any:
        # The area on a map, with the other RVs' areas and the ground stations around it.
        widget = _area_widget(besides=None if obj is None else obj.pk)
        kwargs["widgets"] = {**kwargs.get("widgets", {}), "area": widget}
        return super().get_form(request, obj, change=change, **kwargs)

    def formfield_for_manytomany(
        self, db_field: Any, request: HttpRequest, **kwargs: Any
    ) -> forms.ModelMultipleChoiceField | None:
        if db_field.name == "pilots":  # staff of the pilot group (and superusers)
            kwargs["queryset"] = (
                get_user_model()
                .objects.filter(is_active=True, is_staff=True)
                .filter(Q(groups__name=PILOT) | Q(is_superuser=True))
                .distinct()
                .order_by("username")
            )
        return super().formfield_for_manytomany(db_field, request, **kwargs)

    def get_urls(self) -> list[URLPattern]:
        overview = path(
            "overview/",
            self.admin_site.admin_view(self.overview_view),
            name="fleet_vehicle_overview",
        )
        act = path(
            "overview/<int:object_id>/act/",
            self.admin_site.admin_view(self.act_view),
            name="fleet_vehicle_act",
        )
        logbook = path(
            "<int:object_id>/logbook/",
            self.admin_site.admin_view(self.logbook_view),
            name="fleet_vehicle_logbook",
        )
        return [overview, act, logbook, *super().get_urls()]

    @admin.display(description="logbook")
    def logbook_link(self, vehicle: Vehicle) -> str:
        url = reverse("admin:fleet_vehicle_logbook", args=[vehicle.pk])
        return format_html('<a href="{}">Logbook</a>', url)

    def logbook_view(self, request: HttpRequest, object_id: int) -> TemplateResponse:
        """An RV's logbook: its totals (flights, hours, distance, take-offs and landings, last
        flight), its battery's logbook, what maintenance is due, and its flights, newest
        first, each linked to its page."""
        if not (self.has_view_permission(request) and request.user.has_perm("fleet.view_flight")):
            raise PermissionDenied
        vehicle = get_object_or_404(Vehicle, pk=object_id)
        flights = list(flight_list(vehicle_id=vehicle.pk)[:LOGBOOK_FLIGHTS])
        context = {
            **self.admin_site.each_context(request),
            "title": f"{vehicle.name}: logbook",
            "opts": self.opts,
            "vehicle": vehicle,
            "book": vehicle_logbook(vehicle=vehicle),
            "batteries": vehicle_batteries(vehicle=vehicle),
            "due": vehicle_maintenance(vehicle=vehicle, now=timezone.now()),
            "flights": [(f, _duration_text(f.duration_s)) for f in flights],
            "shown": len(flights),
        }
        return TemplateResponse(request, "admin/fleet/vehicle/logbook.html", context)

    def overview_view(self, request: HttpRequest) -> TemplateResponse:
        """The whole fleet on a map and in a table: status, position, battery, tasks done,
        VVs aboard and whether the RV's worker holds its lease."""
        if not self.has_view_permission(request):
            raise PermissionDenied
        now = timezone.now()
        lease_s = settings.CPCC_RV_LEASE_S
        fleet = list(with_active_vv_count(vehicle_list(), name="vvs_aboard"))
        due = fleet_maintenance(vehicles=fleet, now=now)
        vehicles = [_overview_row(v, now, lease_s, request.user, due.get(v.pk)) for v in fleet]
        stations = [
            {**_station(gs), "alt": gs.alt, "vvs_here": gs.vvs_here}
            for gs in with_active_vv_count(ground_station_list(), name="vvs_here")
        ]
        context = {
            **self.admin_site.each_context(request),
            "title": "Fleet overview",
            "opts": self.opts,
            # The vehicles' symbols are the live map's (CPCCMap.kindMarker).
            "media": map_media(js=("js/map.js", "js/admin/fleet-overview.js")),
            "vehicles": vehicles,
            "stations": stations,
            "map_data": {
                "vehicles": [
                    {k: v for k, v in row.items() if k not in _NOT_FOR_THE_MAP} for row in vehicles
                ],
                "stations": stations,
                "statuses": dict(VehicleStatus.choices),
            },
            "tiles": settings.CPCC_MAP_TILES,
            "lease_s": lease_s,
            "now": now,
            "require_pilot": settings.CPCC_REQUIRE_PILOT,
        }
        return TemplateResponse(request, "admin/fleet/vehicle/overview.html", context)

    def act_view(self, request: HttpRequest, object_id: int) -> HttpResponse:
        """An operator's action on one RV from the fleet overview (POST ``act``: maintenance,
        return, return_home, land, take_duty, hand_over with ``to``: a pilot's id, empty for
        nobody), done once confirmed (``confirmed=yes``, which the page's dialog adds; without
        a script the answer is a page that asks first). Staff who may change vehicles act on
        any RV, pilots (``fleet.operate_vehicle``) on those they are assigned (else 403).
        Audited like every fleet change (django-auditlog: who, when, what changed, the pilot
        in command); then back to the overview with a message."""
        if request.method != "POST":
            return HttpResponseNotAllowed(["POST"])
        user = request.user
        manager = user.has_perm("fleet.change_vehicle")
        if not manager and not user.has_perm("fleet.operate_vehicle"):
            raise PermissionDenied
        vehicle = get_object_or_404(Vehicle, pk=object_id)
        if not manager and not vehicle.pilots.filter(pk=user.pk).exists():
            raise PermissionDenied(
                f"You are not one of {vehicle.name}'s pilots: a fleet manager assigns them."
            )
        act = request.POST.get("act", "")
        if act not in FLEET_ACTIONS:
            known = ", ".join(FLEET_ACTIONS)
            return HttpResponseBadRequest(f"act: {act!r} is not an action; one of {known}.")
        to = None
        if act == "hand_over" and request.POST.get("to"):
            to = self._pilot(vehicle, request.POST["to"])
            if to is None:
                return HttpResponseBadRequest(
                    f"to: {request.POST['to']!r} is not one of {vehicle.name}'s pilots."
                )
        label, _, _ = FLEET_ACTIONS[act]
        if request.POST.get("confirmed") != "yes":
            context = {
                **self.admin_site.each_context(request),
                "title": f"{label}: {vehicle.name}",
                "opts": self.opts,
                "vehicle": vehicle,
                "act": act,
                "label": label,
                "confirm": _confirm(vehicle, act, to),
                "to": "" if to is None else to.pk,
            }
            return TemplateResponse(request, "admin/fleet/vehicle/overview_confirm.html", context)
        try:
            done = self._act(request, vehicle, act, to)
        except (VehicleRemoved, DutyRefused) as exc:
            self.message_user(request, str(exc), messages.ERROR)
        else:
            self.message_user(request, done, messages.SUCCESS)
        return HttpResponseRedirect(reverse("admin:fleet_vehicle_overview"))

    @staticmethod
    def _pilot(vehicle: Vehicle, given: str) -> Any:
        """The pilot of the RV whose id is ``given`` (None: no such pilot of it)."""
        if not given.isdigit():
            return None
        return vehicle.pilots.filter(pk=int(given), is_active=True).first()

    def _act(self, request: HttpRequest, vehicle: Vehicle, act: str, to: Any = None) -> str:
        """Do a confirmed action through its service; what the operator is told."""
        user = request.user
        if act == "take_duty":
            vehicle_take_duty(vehicles=[vehicle], pilot=user, vvm=platform_vvm())
            return f"{vehicle.name}: {user.get_username()} on duty (its pilot in command)"
        if act == "hand_over":
            vehicle_hand_over(vehicles=[vehicle], by=user, to=to, vvm=platform_vvm())
            return f"{vehicle.name}: handed over to {to.get_username() if to else NOBODY}"
        who = f"{user.get_username()} on the fleet overview"
        if act in VehicleCommand.values:
            command = VehicleCommand(act)
            vehicle_command(
                vehicle=vehicle,
                command=command,
                vvm=platform_vvm(),
                reason=f"{command.label.lower()}: asked by {who}",
            )
            return f"{vehicle.name}: {command.label.lower()}, sent to its worker"
        status = VehicleStatus.MAINTENANCE if act == "maintenance" else VehicleStatus.ACTIVE
        vehicle_set_status(
            vehicle=vehicle, status=status, vvm=platform_vvm(), reason=f"set by {who}"
        )
        return f"{vehicle.name}: {status.label.lower()}"

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
        # save_model's service saved the sensors; a vehicle has no inlines. Its pilots are
        # who may operate it (its pilot on duty stays until handed over).
        if "pilots" in form.changed_data:
            form.instance.pilots.set(form.cleaned_data["pilots"])

    def _set_status(
        self, request: HttpRequest, queryset: QuerySet[Vehicle], status: VehicleStatus
    ) -> None:
        vvm = platform_vvm()
        reason = f"set by {request.user.get_username()} in the admin"
        for vehicle in queryset:
            vehicle_set_status(vehicle=vehicle, status=status, vvm=vvm, reason=reason)
        names = ", ".join(v.name for v in queryset)
        self.message_user(request, f"{names}: {status.label.lower()}", messages.SUCCESS)

    # (Staff who may change vehicles: pilots act on their RVs on the fleet overview.)
    @admin.action(
        description="Put into maintenance (VVs aboard move to other RVs)", permissions=["change"]
    )
    def put_into_maintenance(self, request: HttpRequest, queryset: QuerySet[Vehicle]) -> None:
        self._set_status(request, queryset, VehicleStatus.MAINTENANCE)

    @admin.action(description="Return to service", permissions=["change"])
    def return_to_service(self, request: HttpRequest, queryset: QuerySet[Vehicle]) -> None:
        self._set_status(request, queryset, VehicleStatus.ACTIVE)

    @admin.action(
        description="Remove from the fleet (VVs aboard move to other RVs)", permissions=["delete"]
    )
    def remove_from_fleet(self, request: HttpRequest, queryset: QuerySet[Vehicle]) -> None:
        self._set_status(request, queryset, VehicleStatus.REMOVED)


class _Record(admin.ModelAdmin):
    """A record the platform keeps: read by staff who may view it, changed by nobody."""

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False

    def has_delete_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False


@admin.register(PilotDuty)
class PilotDutyAdmin(_Record):
    """Who was the pilot in command of which RV, from when to when, and to whom they handed
    it over (``vehicle_take_duty``, ``vehicle_hand_over``)."""

    list_display = ["vehicle", "pilot_name", "started", "ended", "handed_to_shown"]
    list_filter = ["vehicle"]
    list_select_related = ["vehicle"]
    search_fields = ["vehicle__name", "pilot_name"]
    date_hierarchy = "started"

    @admin.display(description="handed to", ordering="handed_to")
    def handed_to_shown(self, duty: PilotDuty) -> str:
        if duty.ended is None:
            return "on duty"
        return duty.handed_to or NOBODY


def _duration_text(seconds: float | None) -> str:
    if seconds is None:
        return "in flight"
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes} min {rest:02d} s"


# The flights an RV's logbook page lists (the CSV export has them all).
LOGBOOK_FLIGHTS = 200


@admin.register(Flight)
class FlightAdmin(_Record):
    """Every flight of an RV, take-off to landing, with its pilot in command, as its worker
    recorded it."""

    list_display = [
        "vehicle",
        "started",
        "pilot_shown",
        "duration_shown",
        "distance_shown",
        "tasks_served",
        "ended_how",
    ]
    list_filter = ["vehicle", "ended_how"]
    list_select_related = ["vehicle"]
    search_fields = ["vehicle__name", "pilot_name"]
    date_hierarchy = "started"

    @admin.display(description="pilot in command", ordering="pilot_name")
    def pilot_shown(self, flight: Flight) -> str:
        return flight.pilot_name or "none on duty"

    @admin.display(description="duration", ordering="duration_s")
    def duration_shown(self, flight: Flight) -> str:
        return _duration_text(flight.duration_s)

    def change_view(
        self,
        request: HttpRequest,
        object_id: str,
        form_url: str = "",
        extra_context: dict[str, Any] | None = None,
    ) -> Any:
        """A flight's page: its facts, where it flew with a replay, its altitude and battery
        over time, the tasks it served and its log (a record: nothing to change)."""
        if request.method != "GET" or not self.has_view_permission(request):
            return super().change_view(request, object_id, form_url, extra_context)
        flight = self.get_object(request, object_id)
        if flight is None:
            return self._get_obj_does_not_exist_redirect(request, self.opts, object_id)
        tasks = flight_tasks(flight=flight)
        context = {
            **self.admin_site.each_context(request),
            "title": f"{flight.vehicle.name}, {flight.started:%Y-%m-%d %H:%M} UTC",
            "opts": self.opts,
            "flight": flight,
            "duration": _duration_text(flight.duration_s),
            "tasks": tasks,
            "track": bool(flight.track),
            "log_kept": flight_log_kept(flight=flight),
            "media": map_media(),
            "page_data": {
                "track": flight.track,
                "started_s": flight.started_s,
                "tiles": settings.CPCC_MAP_TILES,
            },
        }
        return TemplateResponse(request, "admin/fleet/flight/page.html", context)

    @admin.display(description="distance", ordering="distance_m")
    def distance_shown(self, flight: Flight) -> str:
        return "" if flight.distance_m is None else f"{flight.distance_m / 1000:.2f} km"


# --- batteries and maintenance ------------------------------------------------------------------


@admin.register(Battery)
class BatteryAdmin(ExplainedWhenEmpty):
    """The batteries: their logbooks (cycles, flights, hours, lowest charge), the RV each is in,
    what is due and whether it is retired. A swap is recorded as maintenance (or seen from the
    autopilot's battery id or serial): the RV a battery is in is not changed here."""

    empty_list_help = (
        "A battery appears when an RV's worker reports its charge (named by the autopilot's "
        "battery id or serial, else after its RV), or when someone records a battery swap "
        "(Maintenance records, add: battery put in). " + CYCLE_RULE
    )
    list_display = [
        "name",
        "vehicle",
        "cycles",
        "flights",
        "hours_shown",
        "lowest_pct",
        "due_shown",
        "retired",
    ]
    list_filter = [("retired", admin.EmptyFieldListFilter), "vehicle"]
    list_select_related = ["vehicle"]
    search_fields = ["name", "serial", "vehicle__name"]
    fields = [
        "name",
        "serial",
        "autopilot_id",
        "vehicle",
        "installed",
        "cycles",
        "flights",
        "flight_s",
        "lowest_pct",
        "retired",
        "created",
    ]
    readonly_fields = [
        "vehicle",
        "installed",
        "cycles",
        "flights",
        "flight_s",
        "lowest_pct",
        "retired",
        "created",
    ]

    @admin.display(description="flight hours", ordering="flight_s")
    def hours_shown(self, battery: Battery) -> str:
        return f"{battery.flight_s / 3600:.2f}"

    @admin.display(description="due")
    def due_shown(self, battery: Battery) -> str:
        due = battery_due_list(batteries=[battery])[battery.pk]
        return "; ".join(_due_text(d) for d in due) or "-"


@admin.register(MaintenanceInterval)
class MaintenanceIntervalAdmin(ExplainedWhenEmpty):
    """Maintenance intervals: for the RVs of a kind, one RV or every RV, every so many flight
    hours, flights or days, and their batteries' cycles. Saving or deleting one looks at the
    fleet again: an RV now overdue is grounded, one no longer overdue goes back into service."""

    empty_list_help = (
        "A maintenance interval says when maintenance is due ('25-hour inspection': every 25 "
        "flight hours), for every RV, the RVs of a kind or one RV, and when a battery is "
        "serviced or retired (by its cycles). Due soon at 90 %; overdue, the RV is grounded "
        "until someone records the maintenance."
    )
    list_display = [
        "name",
        "applies_to",
        "every_hours",
        "every_flights",
        "every_days",
        "every_cycles",
        "retire_cycles",
    ]
    list_filter = ["kind", "vehicle"]
    search_fields = ["name"]
    fields = [
        "name",
        ("kind", "vehicle"),
        ("every_hours", "every_flights", "every_days"),
        ("every_cycles", "retire_cycles"),
    ]

    @admin.display(description="for")
    def applies_to(self, interval: MaintenanceInterval) -> str:
        if interval.vehicle is not None:
            return str(interval.vehicle)
        return interval.get_kind_display() if interval.kind else "every RV"

    def _fleet_checked(self, request: HttpRequest) -> None:
        grounded = vehicles_check_maintenance(vvm=platform_vvm())
        if grounded:
            self.message_user(
                request, f"Grounded (overdue): {', '.join(grounded)}", messages.WARNING
            )

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        super().save_model(request, obj, form, change)
        self._fleet_checked(request)

    def delete_model(self, request: HttpRequest, obj: Any) -> None:
        super().delete_model(request, obj)
        self._fleet_checked(request)

    def delete_queryset(self, request: HttpRequest, queryset: QuerySet[Any]) -> None:
        super().delete_queryset(request, queryset)
        self._fleet_checked(request)


class MaintenanceRecordForm(forms.ModelForm):
    """Maintenance done: on an RV or a battery, an interval's or in words; or a battery swap
    (the battery put in, by name)."""

    swap_to = forms.CharField(
        required=False,
        max_length=120,
        label="Battery put in",
        help_text="A battery swap on the vehicle: the name of the battery put in (a new name "
        "makes one). Leave the rest empty but the notes.",
    )

    class Meta:
        model = MaintenanceRecord
        fields = ["vehicle", "battery", "interval", "what", "notes"]

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if "what" in self.fields:  # (the record's page shows it read-only)
            self.fields["what"].required = False
            self.fields["what"].help_text = "What was done, in words (empty: the interval's name)."

    def clean(self) -> dict[str, Any]:
        data = super().clean() or {}
        if data.get("swap_to") and data.get("vehicle") is None:
            raise forms.ValidationError({"vehicle": "name the vehicle whose battery was swapped"})
        if data.get("vehicle") is None and data.get("battery") is None:
            raise forms.ValidationError("name the vehicle or the battery maintained")
        if not data.get("swap_to") and data.get("interval") is None and not data.get("what"):
            raise forms.ValidationError({"what": "say what was done, or choose the interval"})
        swap_to, vehicle, interval = data.get("swap_to"), data.get("vehicle"), data.get("interval")
        if swap_to and Battery.objects.filter(name=swap_to.strip(), retired__isnull=False):
            raise forms.ValidationError({"swap_to": f"battery {swap_to} is retired"})
        if interval is not None and vehicle is not None and not intervals_for(vehicle, [interval]):
            raise forms.ValidationError({"interval": f"{interval} is not one of {vehicle}'s"})
        return data


@admin.register(MaintenanceRecord)
class MaintenanceRecordAdmin(ExplainedWhenEmpty):
    """Maintenance records: who did what, when, on which RV or battery. Added through the
    service (an RV grounded for it goes back into service), never changed or deleted."""

    form = MaintenanceRecordForm
    empty_list_help = (
        "A maintenance record says who did what maintenance on an RV or a battery, and when; "
        "recording an interval's maintenance starts it again and puts an RV grounded for it "
        "back into service. A battery swap is recorded here too."
    )
    list_display = ["at", "what", "vehicle", "battery", "by_name"]
    list_filter = ["vehicle", "interval"]
    list_select_related = ["vehicle", "battery"]
    search_fields = ["what", "by_name", "vehicle__name", "battery__name", "notes"]
    date_hierarchy = "at"

    def get_fields(self, request: HttpRequest, obj: Any = None) -> list[str]:
        if obj is None:
            return ["vehicle", "battery", "interval", "what", "swap_to", "notes"]
        return ["vehicle", "battery", "interval", "what", "notes", "by_name", "at"]

    def get_readonly_fields(self, request: HttpRequest, obj: Any = None) -> list[str]:
        if obj is None:
            return []
        return ["vehicle", "battery", "interval", "what", "notes", "by_name", "at"]

    def has_change_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False

    def has_delete_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        data = form.cleaned_data
        if data.get("swap_to"):
            battery = battery_swap(
                vehicle=data["vehicle"],
                name=data["swap_to"],
                by=request.user,
                notes=data.get("notes", ""),
                vvm=platform_vvm(),
            )
            saved = battery.maintenance_records.order_by("-at", "-id")[0]
        else:
            saved = maintenance_record(
                vehicle=data.get("vehicle"),
                battery=data.get("battery"),
                interval=data.get("interval"),
                by=request.user,
                what=data.get("what", ""),
                notes=data.get("notes", ""),
                vvm=platform_vvm(),
            )
        # The admin logs and shows the record as the service saved it.
        for model_field in MaintenanceRecord._meta.concrete_fields:
            setattr(obj, model_field.attname, getattr(saved, model_field.attname))

    def save_related(self, request: HttpRequest, form: Any, formsets: Any, change: bool) -> None:
        pass  # the service saved it
