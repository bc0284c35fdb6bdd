"""The SDC, vehicle and ground-station endpoints of the REST API (DESIGN.md section 6).

``/api/v1/sensors/`` is for everyone (each sees the entries they may use); vehicles and ground
stations are for platform staff only.
"""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from django.db.models import QuerySet
from django.utils import timezone
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import (
    OpenApiParameter,
    OpenApiResponse,
    extend_schema,
    extend_schema_view,
)
from rest_framework import generics, mixins, status, viewsets
from rest_framework.decorators import action
from rest_framework.exceptions import NotFound, PermissionDenied, ValidationError
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response

from accounts.models import User
from accounts.selectors import sensor_list_for_user
from cpcc_site.api import Conflict, DetailSerializer, object_id, refusal
from cpcc_site.permissions import StaffPermission
from fleet.api.serializers import (
    BatterySwapInSerializer,
    DutyGroupSerializer,
    GroundStationInSerializer,
    GroundStationOutSerializer,
    HandOverSerializer,
    LogbookSerializer,
    MaintenanceRecordInSerializer,
    SensorOutSerializer,
    StaffSensorOutSerializer,
    VehicleInSerializer,
    VehicleOutSerializer,
)
from fleet.maintenance import fleet_maintenance, vehicle_batteries
from fleet.models import (
    GroundStation,
    MaintenanceInterval,
    SensorType,
    Vehicle,
    VehicleCommand,
    VehicleStatus,
)
from fleet.selectors import ground_station_list, vehicle_list, vehicle_logbook
from missions.selectors import with_active_vv_count
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    DutyRefused,
    GroundStationBusy,
    VehicleRemoved,
    battery_swap,
    ground_station_create,
    ground_station_delete,
    ground_station_update,
    maintenance_record,
    vehicle_command,
    vehicle_create,
    vehicle_hand_over,
    vehicle_set_status,
    vehicle_take_duty,
    vehicle_update,
)

STAFF_ERRORS = {403: DetailSerializer, 404: DetailSerializer}
# Model fields that the API shows as one field.
API_FIELD = {"depot_lat": "depot", "depot_lng": "depot", "depot_alt": "depot"}
API_FIELD |= {"lat": "position", "lng": "position", "alt": "position"}


class FleetErrorsMixin:
    """Validation errors of the services (Django's) as 400 JSON naming the API's fields; a
    missing object as 404 saying which."""

    noun = "object"

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, DjangoValidationError):
            exc = refusal(exc, API_FIELD)
        elif isinstance(exc, DutyRefused):
            exc = Conflict(str(exc))
        elif isinstance(exc, VehicleRemoved):
            exc = Conflict(f"{exc.vehicle.name} was removed from the fleet: it takes no command.")
        elif isinstance(exc, GroundStationBusy):
            exc = Conflict(
                f"{exc.station.name} holds {exc.count} VV(s) that have not ended; "
                "remove it once they have."
            )
        return super().handle_exception(exc)  # type: ignore[misc, no-any-return]

    def get_object(self) -> Any:
        try:
            return self.get_queryset().get(pk=object_id(self.kwargs["pk"]))  # type: ignore[attr-defined]
        except (ValueError, TypeError, Vehicle.DoesNotExist, GroundStation.DoesNotExist):
            raise NotFound(f"No {self.noun} with id {self.kwargs['pk']!r}.") from None  # type: ignore[attr-defined]


class SensorListView(generics.ListAPIView):  # type: ignore[type-arg]
    """The SDC entries you may use in a VV: ``{name, description, kind, unit, params}`` as
    ``VV.sensor.list()`` shows them. Staff see every entry, with ``privileged``."""

    def get_serializer_class(self) -> type[SensorOutSerializer]:
        return StaffSensorOutSerializer if self.request.user.is_staff else SensorOutSerializer

    def get_queryset(self) -> QuerySet[SensorType]:
        return sensor_list_for_user(user=self.request.user)  # type: ignore[arg-type]


def _vehicle_command_schema(what: str, *, refused: bool = False) -> Any:
    errors = {**STAFF_ERRORS, 409: DetailSerializer} if refused else STAFF_ERRORS
    return extend_schema(
        request=None, responses={200: VehicleOutSerializer, **errors}, description=what
    )


# Rules a schema cannot say, each a 400 naming the field.
VEHICLE_REFUSED = OpenApiResponse(
    OpenApiTypes.OBJECT,
    description="A value is malformed, or breaks a rule the schema cannot say: the area is not "
    "a closed ring of at least 3 distinct points that does not cross itself, a sensor is not "
    "in the catalog, a sensor source does not fit its sensor, max_altitude_m is below "
    "min_altitude_m, the altitudes or the speed are beyond what its kind can do (ground and "
    "surface vehicles stay at 0 m, only underwater ones go below 0), its kind cannot carry a "
    "sensor. The body names the field.",
)


@extend_schema_view(
    list=extend_schema(
        parameters=[
            OpenApiParameter(
                "status", enum=VehicleStatus.values, description="only vehicles in this state"
            )
        ]
    ),
    retrieve=extend_schema(responses={200: VehicleOutSerializer, **STAFF_ERRORS}),
    create=extend_schema(
        request=VehicleInSerializer,
        responses={
            201: VehicleOutSerializer,
            400: VEHICLE_REFUSED,
            409: DetailSerializer,
            403: DetailSerializer,
        },
    ),
    partial_update=extend_schema(
        request=VehicleInSerializer,
        responses={
            200: VehicleOutSerializer,
            400: VEHICLE_REFUSED,
            409: DetailSerializer,
            **STAFF_ERRORS,
        },
    ),
    destroy=extend_schema(
        responses={200: VehicleOutSerializer, **STAFF_ERRORS},
        description="The same as POST .../remove/: the vehicle is kept, with status removed.",
    ),
)
class VehicleViewSet(
    FleetErrorsMixin,
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """The real vehicles (staff only): add one, change its configuration, and put it into
    maintenance, back into service, or remove it with explicit commands. A removed vehicle is
    kept, with status ``removed``; the VVs aboard a vehicle leaving service move on unnoticed."""

    permission_classes = [IsAuthenticated, StaffPermission]
    serializer_class = VehicleOutSerializer
    http_method_names = ["get", "post", "patch", "delete", "head", "options"]
    noun = "vehicle"
    staff_model = Vehicle
    # A pilot operates the RVs they are assigned (checked per RV); a fleet manager any.
    staff_perms = {
        action: ("fleet.operate_vehicle",)
        for action in (
            "maintenance",
            "return_",
            "return_home",
            "land",
            "take_duty",
            "hand_over",
            "take_duty_group",
            "hand_over_group",
        )
    } | {
        "remove": ("fleet.delete_vehicle",),
        "logbook": ("fleet.view_flight",),
        "maintenance_record": ("fleet.add_maintenancerecord",),
        # A pilot records a swap on the RVs they are assigned (checked per RV).
        "battery": ("fleet.swap_battery",),
    }

    def get_queryset(self) -> QuerySet[Vehicle]:
        wanted = self.request.query_params.get("status")
        if wanted is not None and wanted not in VehicleStatus.values:
            raise ValidationError(
                {
                    "status": [
                        f"{wanted!r} is not a status; one of {', '.join(VehicleStatus.values)}."
                    ]
                }
            )
        return self._vehicles(status=wanted or None)

    def get_object(self) -> Vehicle:
        """A vehicle in the fleet: a removed one is gone for the API (404), though its record
        stays for its history (``?status=removed`` in the list, the admin)."""
        vehicle: Vehicle = super().get_object()
        if vehicle.status == VehicleStatus.REMOVED:
            raise NotFound(
                f"Vehicle {self.kwargs['pk']!r} was removed from the fleet; its record is "
                "listed with ?status=removed."
            )
        return vehicle

    def get_serializer(self, *args: Any, **kwargs: Any) -> Any:
        # What is due on the RVs shown, read for all of them at once.
        shown = args[0] if args else kwargs.get("instance")
        if isinstance(shown, Vehicle | list | QuerySet):
            vehicles = [shown] if isinstance(shown, Vehicle) else list(shown)
            kwargs["context"] = self.get_serializer_context() | {
                "maintenance": fleet_maintenance(vehicles=vehicles, now=timezone.now())
            }
        return super().get_serializer(*args, **kwargs)

    @staticmethod
    def _vehicles(status: str | None = None) -> QuerySet[Vehicle]:
        return with_active_vv_count(vehicle_list(status=status), name="vvs_aboard")

    def _shown(self, vehicle: Vehicle, code: int = status.HTTP_200_OK) -> Response:
        fresh = self._vehicles().get(pk=vehicle.pk)
        return Response(self.get_serializer(fresh).data, status=code)

    def create(self, request: Request) -> Response:
        given = VehicleInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        vehicle = vehicle_create(
            config=given.config(), sensors=given.sensor_names() or [], vvm=platform_vvm()
        )
        return self._shown(vehicle, status.HTTP_201_CREATED)

    def partial_update(self, request: Request, pk: str) -> Response:
        given = VehicleInSerializer(data=request.data, partial=True)
        given.is_valid(raise_exception=True)
        vehicle = vehicle_update(
            vehicle=self.get_object(),
            config=given.config(),
            sensors=given.sensor_names(),
            vvm=platform_vvm(),
        )
        return self._shown(vehicle)

    def _operated(self) -> Vehicle:
        """The RV an operator's action names: a pilot may act only on the RVs they are
        assigned; staff who may change vehicles on any."""
        vehicle = self.get_object()
        user = self.request.user
        if (
            not user.has_perm("fleet.change_vehicle")
            and not vehicle.pilots.filter(pk=user.pk).exists()
        ):
            raise PermissionDenied(
                f"You are not one of {vehicle.name}'s pilots: a fleet manager assigns them."
            )
        return vehicle

    def _set_status(self, status_: VehicleStatus) -> Response:
        operated = status_ in (VehicleStatus.MAINTENANCE, VehicleStatus.ACTIVE)
        vehicle = self._operated() if operated else self.get_object()
        vehicle_set_status(
            vehicle=vehicle,
            status=status_,
            vvm=platform_vvm(),
            reason=f"set by {self.request.user.get_username()} over the API",
        )
        return self._shown(vehicle)

    def destroy(self, request: Request, pk: str) -> Response:
        return self._set_status(VehicleStatus.REMOVED)

    @_vehicle_command_schema("Take the vehicle out of service for maintenance or recharging.")
    @action(detail=True, methods=["post"])
    def maintenance(self, request: Request, pk: str) -> Response:
        return self._set_status(VehicleStatus.MAINTENANCE)

    @_vehicle_command_schema("Put the vehicle (back) into service.")
    @action(detail=True, methods=["post"], url_path="return", url_name="return")
    def return_(self, request: Request, pk: str) -> Response:
        return self._set_status(VehicleStatus.ACTIVE)

    @_vehicle_command_schema("Remove the vehicle from the fleet; it is kept, with status removed.")
    @action(detail=True, methods=["post"])
    def remove(self, request: Request, pk: str) -> Response:
        return self._set_status(VehicleStatus.REMOVED)

    # An operator's commands: the vehicle goes into maintenance at once (its VVs move on) and
    # its worker obeys the command once; it stays in maintenance until .../return/.

    def _command(self, command: VehicleCommand) -> Response:
        vehicle = vehicle_command(
            vehicle=self._operated(),
            command=command,
            vvm=platform_vvm(),
            reason=f"{command.label.lower()}: asked by {self.request.user.get_username()} "
            "over the API",
        )
        return self._shown(vehicle)

    @_vehicle_command_schema(
        "Return home now: the vehicle goes into maintenance (its VVs move on) and flies home "
        "(a MAVLink autopilot gets MAV_CMD_NAV_RETURN_TO_LAUNCH) and lands; back into service "
        "with .../return/. `command_taken` says when its worker took the command. 404 for a "
        "removed vehicle (409 if it was removed while the command was on its way).",
        refused=True,
    )
    @action(detail=True, methods=["post"], url_path="return-home", url_name="return-home")
    def return_home(self, request: Request, pk: str) -> Response:
        return self._command(VehicleCommand.RETURN_HOME)

    @_vehicle_command_schema(
        "Land now, where the vehicle is: it goes into maintenance (its VVs move on) and lands "
        "(a MAVLink autopilot gets MAV_CMD_NAV_LAND); back into service with .../return/. "
        "404 for a removed vehicle (409 if it was removed while the command was on its way).",
        refused=True,
    )
    @action(detail=True, methods=["post"])
    def land(self, request: Request, pk: str) -> Response:
        return self._command(VehicleCommand.LAND)

    @extend_schema(
        request=None,
        responses={200: LogbookSerializer, **STAFF_ERRORS},
        description="The vehicle's logbook from its recorded flights: flights (landed), "
        "take-offs, landings, flight hours, distance, its last take-off, whether it flies now.",
    )
    @action(detail=True, methods=["get"])
    def logbook(self, request: Request, pk: str) -> Response:
        vehicle: Vehicle = super().get_object()  # a removed RV's logbook stays readable
        logbook = vehicle_logbook(vehicle=vehicle) | {
            "batteries": vehicle_batteries(vehicle=vehicle)
        }
        return Response(LogbookSerializer(logbook).data)

    # Maintenance: recording it (which puts an RV grounded for it back into service) and a
    # battery swap (which lifts a grounding for a retired battery).

    @extend_schema(
        request=MaintenanceRecordInSerializer,
        responses={200: VehicleOutSerializer, 400: OpenApiTypes.OBJECT, **STAFF_ERRORS},
        description="Record maintenance done on the vehicle: a maintenance interval's (its id; "
        "the interval starts again) or what was done in words, with notes; kept with who and "
        "when, in the audit log. A vehicle grounded for it goes back into service (never one "
        "a person put into maintenance). Fleet managers.",
    )
    @action(
        detail=True, methods=["post"], url_path="maintenance-record", url_name="maintenance-record"
    )
    def maintenance_record(self, request: Request, pk: str) -> Response:
        vehicle = self.get_object()
        given = MaintenanceRecordInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        data = given.validated_data
        interval = None
        if "interval" in data:
            interval = MaintenanceInterval.objects.filter(pk=data["interval"]).first()
            if interval is None:
                raise ValidationError(
                    {"interval": [f"No maintenance interval {data['interval']}."]}
                )
        maintenance_record(
            vehicle=vehicle,
            interval=interval,
            by=request.user,
            what=data.get("what", ""),
            notes=data.get("notes", ""),
            vvm=platform_vvm(),
        )
        return self._shown(vehicle)

    @extend_schema(
        request=BatterySwapInSerializer,
        responses={200: VehicleOutSerializer, 400: OpenApiTypes.OBJECT, **STAFF_ERRORS},
        description="Record a battery swap: the battery of that name (a new name makes one) is "
        "in the vehicle now; its cycles, flights and hours count from here. A vehicle grounded "
        "for its retired battery goes back into service; a retired battery is refused (400). "
        "Its pilots, and fleet managers.",
    )
    @action(detail=True, methods=["post"])
    def battery(self, request: Request, pk: str) -> Response:
        vehicle = self._operated()
        given = BatterySwapInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        battery_swap(
            vehicle=vehicle,
            name=given.validated_data["name"],
            by=request.user,
            notes=given.validated_data.get("notes", ""),
            vvm=platform_vvm(),
        )
        return self._shown(vehicle)

    # A pilot in command: taking an RV (or a group) on duty and handing it over.

    @extend_schema(
        request=None,
        responses={200: VehicleOutSerializer, **STAFF_ERRORS, 409: DetailSerializer},
        description="Take the vehicle on duty: you become its pilot in command (recorded with "
        "its take-offs and in the audit log with every command). You must be one of its "
        "pilots; 409 while another pilot is on duty (they hand it over first).",
    )
    @action(detail=True, methods=["post"], url_path="take-duty", url_name="take-duty")
    def take_duty(self, request: Request, pk: str) -> Response:
        vehicle_take_duty(vehicles=[self.get_object()], pilot=request.user, vvm=platform_vvm())
        return self._shown(self.get_object())

    @extend_schema(
        request=HandOverSerializer,
        responses={200: VehicleOutSerializer, **STAFF_ERRORS, 409: DetailSerializer},
        description="Hand the vehicle over to another of its pilots (``to``), or to nobody. "
        "Its pilot on duty does, or staff who may change vehicles. With CPCC_REQUIRE_PILOT a "
        "vehicle with no pilot on duty takes no new work.",
    )
    @action(detail=True, methods=["post"], url_path="hand-over", url_name="hand-over")
    def hand_over(self, request: Request, pk: str) -> Response:
        given = HandOverSerializer(data=request.data or {})
        given.is_valid(raise_exception=True)
        vehicle_hand_over(
            vehicles=[self.get_object()],
            by=request.user,
            to=self._pilot(given.validated_data.get("to")),
            vvm=platform_vvm(),
        )
        return self._shown(self.get_object())

    @extend_schema(
        request=DutyGroupSerializer,
        responses={200: VehicleOutSerializer(many=True), **STAFF_ERRORS, 409: DetailSerializer},
        description="Take several vehicles on duty at once (all or none), as .../take-duty/.",
        operation_id="vehicles_take_duty_group",
    )
    @action(detail=False, methods=["post"], url_path="take-duty", url_name="take-duty-group")
    def take_duty_group(self, request: Request) -> Response:
        vehicles, _ = self._group(request)
        vehicle_take_duty(vehicles=vehicles, pilot=request.user, vvm=platform_vvm())
        return self._shown_group(vehicles)

    @extend_schema(
        request=DutyGroupSerializer,
        responses={200: VehicleOutSerializer(many=True), **STAFF_ERRORS, 409: DetailSerializer},
        description="Hand several vehicles over at once (all or none), as .../hand-over/.",
        operation_id="vehicles_hand_over_group",
    )
    @action(detail=False, methods=["post"], url_path="hand-over", url_name="hand-over-group")
    def hand_over_group(self, request: Request) -> Response:
        vehicles, given = self._group(request)
        to = self._pilot(given.get("to"))
        vehicle_hand_over(vehicles=vehicles, by=request.user, to=to, vvm=platform_vvm())
        return self._shown_group(vehicles)

    def _group(self, request: Request) -> tuple[list[Vehicle], dict[str, Any]]:
        """The vehicles a group's body names (404 for one not in the fleet), and the body."""
        given = DutyGroupSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        wanted = list(dict.fromkeys(given.validated_data["vehicles"]))
        found = {v.pk: v for v in self._vehicles().filter(pk__in=wanted)}
        missing = [pk for pk in wanted if pk not in found or found[pk].status == "removed"]
        if missing:
            raise NotFound(f"No vehicle with id {missing[0]!r}.")
        return [found[pk] for pk in wanted], given.validated_data

    def _shown_group(self, vehicles: list[Vehicle]) -> Response:
        fresh = self._vehicles().filter(pk__in=[v.pk for v in vehicles])
        return Response(self.get_serializer(fresh, many=True).data)

    @staticmethod
    def _pilot(username: str | None) -> User | None:
        if username is None:
            return None
        pilot = User.objects.filter(username=username, is_active=True, is_staff=True).first()
        if pilot is None:
            raise ValidationError({"to": [f"No pilot named {username!r}."]})
        return pilot


@extend_schema_view(
    retrieve=extend_schema(responses={200: GroundStationOutSerializer, **STAFF_ERRORS}),
    create=extend_schema(
        request=GroundStationInSerializer,
        responses={
            201: GroundStationOutSerializer,
            400: OpenApiTypes.OBJECT,
            409: DetailSerializer,
            403: DetailSerializer,
        },
    ),
    update=extend_schema(
        request=GroundStationInSerializer,
        responses={
            200: GroundStationOutSerializer,
            400: OpenApiTypes.OBJECT,
            409: DetailSerializer,
            **STAFF_ERRORS,
        },
    ),
    partial_update=extend_schema(
        request=GroundStationInSerializer,
        responses={
            200: GroundStationOutSerializer,
            400: OpenApiTypes.OBJECT,
            409: DetailSerializer,
            **STAFF_ERRORS,
        },
    ),
    destroy=extend_schema(responses={204: None, 409: DetailSerializer, **STAFF_ERRORS}),
)
class GroundStationViewSet(
    FleetErrorsMixin,
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """The ground stations (staff only). One holding VVs that have not ended cannot be deleted."""

    permission_classes = [IsAuthenticated, StaffPermission]
    serializer_class = GroundStationOutSerializer
    noun = "ground station"
    staff_model = GroundStation

    def get_queryset(self) -> QuerySet[GroundStation]:
        return with_active_vv_count(ground_station_list(), name="vvs_here")

    def _shown(self, station: GroundStation, code: int = status.HTTP_200_OK) -> Response:
        fresh = self.get_queryset().get(pk=station.pk)
        return Response(self.get_serializer(fresh).data, status=code)

    def create(self, request: Request) -> Response:
        given = GroundStationInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        station = ground_station_create(config=given.config(), vvm=platform_vvm())
        return self._shown(station, status.HTTP_201_CREATED)

    def update(self, request: Request, pk: str, partial: bool = False) -> Response:
        given = GroundStationInSerializer(data=request.data, partial=partial)
        given.is_valid(raise_exception=True)
        station = ground_station_update(station=self.get_object(), config=given.config())
        return self._shown(station)

    def partial_update(self, request: Request, pk: str) -> Response:
        return self.update(request, pk, partial=True)

    def destroy(self, request: Request, pk: str) -> Response:
        ground_station_delete(station=self.get_object())
        return Response(status=status.HTTP_204_NO_CONTENT)
