"""The flights of the fleet (staff): each RV's take-off to landing with its pilot in command,
its MAVLink log, a CSV of a period for an authority or an insurer; and an RV's logbook."""

from __future__ import annotations

import csv
import datetime as dt
import io
from typing import Any

from django.http import FileResponse, HttpResponse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiParameter, OpenApiResponse, extend_schema
from rest_framework import generics, serializers
from rest_framework.exceptions import NotFound, ValidationError
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request

from cpcc_site.api import DetailSerializer, FileOrJSONNegotiation, object_id
from cpcc_site.permissions import StaffPermission
from fleet.models import Flight
from fleet.selectors import flight_list
from missions.api.service_levels import parse_instant
from vvm_worker.services.flight_logs import flight_log_kept, flight_log_simulated

TLOG_TYPE = "application/octet-stream"
CSV_TYPE = "text/csv"
STAFF_ERRORS = {403: DetailSerializer, 404: DetailSerializer}

FILTERS = [
    OpenApiParameter("vehicle", OpenApiTypes.INT, description="only this vehicle's (its id)"),
    OpenApiParameter(
        "from", OpenApiTypes.STR, description="took off at or after (epoch seconds or ISO 8601)"
    ),
    OpenApiParameter("to", OpenApiTypes.STR, description="took off before (same forms)"),
]


class FlightOutSerializer(serializers.ModelSerializer):
    """A flight as the logbook keeps it."""

    vehicle = serializers.SlugRelatedField(slug_field="name", read_only=True)
    vehicle_id = serializers.IntegerField(read_only=True)
    pilot_in_command = serializers.CharField(
        source="pilot_name", read_only=True, help_text="Empty: no pilot was on duty."
    )
    log = serializers.SerializerMethodField(help_text="The log's URL, or null when none is kept.")

    class Meta:
        model = Flight
        fields = [
            "id",
            "vehicle",
            "vehicle_id",
            "pilot_in_command",
            "started",
            "ended",
            "ended_how",
            "duration_s",
            "distance_m",
            "max_alt_m",
            "battery_start_pct",
            "battery_end_pct",
            "battery_name",
            "tasks_served",
            "customers",
            "vvs",
            "log",
        ]

    def get_log(self, flight: Flight) -> str | None:
        if not flight_log_kept(flight=flight):
            return None
        return f"/api/v1/flights/{flight.pk}/log.tlog"


def _period(request: Request) -> dict[str, Any]:
    """The filters of the query string: vehicle, from, to (400 naming a bad one)."""
    found: dict[str, Any] = {}
    raw_vehicle = request.query_params.get("vehicle") or None  # (empty: no filter)
    if raw_vehicle is not None:
        try:
            value = int(raw_vehicle)
        except ValueError:
            raise ValidationError({"vehicle": [f"{raw_vehicle!r} is not a vehicle id."]}) from None
        # An id no vehicle has (0, one beyond the id column) has no flights.
        found["vehicle_id"] = value if 0 < value < 2**63 else 0
    for name, key in (("from", "since"), ("to", "until")):
        raw = request.query_params.get(name)
        if not raw:
            continue
        try:
            found[key] = dt.datetime.fromtimestamp(parse_instant(raw), dt.UTC)
        except (ValueError, OverflowError, OSError) as exc:
            raise ValidationError({name: [str(exc)]}) from None
    if found.get("since") and found.get("until") and found["since"] >= found["until"]:
        raise ValidationError({"from": ["must be before to"]})
    return found


class _Flights:
    permission_classes = [IsAuthenticated, StaffPermission]
    staff_model = Flight
    noun = "flight"


@extend_schema(summary="The fleet's flights, newest first (staff)", parameters=FILTERS)
class FlightListView(_Flights, generics.ListAPIView):  # type: ignore[type-arg]
    """Every flight of the fleet, take-off to landing (one in the air has no ``ended``)."""

    serializer_class = FlightOutSerializer

    def get_queryset(self) -> Any:
        return flight_list(**_period(self.request))


@extend_schema(summary="One flight (staff)", responses={200: FlightOutSerializer, **STAFF_ERRORS})
class FlightDetailView(_Flights, generics.RetrieveAPIView):  # type: ignore[type-arg]
    serializer_class = FlightOutSerializer

    def get_object(self) -> Flight:
        try:
            return flight_list().get(pk=object_id(self.kwargs["pk"]))
        except (ValueError, Flight.DoesNotExist):
            raise NotFound("No flight with this id (GET /api/v1/flights/ lists them).") from None


@extend_schema(
    summary="A flight's MAVLink telemetry log (.tlog: Mission Planner, QGroundControl, "
    "mavlogdump.py) (staff)",
    responses={
        (200, TLOG_TYPE): OpenApiResponse(OpenApiTypes.BINARY, description="the .tlog"),
        **STAFF_ERRORS,
    },
)
class FlightLogView(FlightDetailView):
    content_negotiation_class = FileOrJSONNegotiation

    def get(self, request: Request, *args: Any, **kwargs: Any) -> Any:
        flight = self.get_object()
        if not flight_log_kept(flight=flight):
            raise NotFound(
                "No log is kept of this flight (none was recorded, or it is older than "
                "CPCC_FLIGHT_LOG_DAYS)."
            )
        name = f"{flight.vehicle.name}-{flight.started:%Y%m%dT%H%M%SZ}.tlog".replace(" ", "_")
        if flight.log:
            return FileResponse(
                flight.log.open("rb"), as_attachment=True, filename=name, content_type=TLOG_TYPE
            )
        # A simulated RV's: the simulator's messages along its track, made now.
        response = HttpResponse(flight_log_simulated(flight=flight), content_type=TLOG_TYPE)
        response["Content-Disposition"] = f'attachment; filename="{name}"'
        return response


CSV_COLUMNS = [
    "flight",
    "vehicle",
    "pilot_in_command",
    "take_off_utc",
    "landing_utc",
    "duration_min",
    "distance_km",
    "max_altitude_m",
    "battery",
    "battery_start_pct",
    "battery_end_pct",
    "tasks_served",
    "customers",
    "ended_how",
]


@extend_schema(
    summary="The flights of a period as CSV, for an authority or an insurer (staff)",
    parameters=FILTERS,
    responses={
        (200, CSV_TYPE): OpenApiResponse(OpenApiTypes.STR, description="one flight a row"),
        400: OpenApiTypes.OBJECT,
        403: DetailSerializer,
    },
)
class FlightCSVView(_Flights, generics.GenericAPIView):  # type: ignore[type-arg]
    content_negotiation_class = FileOrJSONNegotiation
    serializer_class = FlightOutSerializer

    def get(self, request: Request) -> HttpResponse:
        flights = flight_list(**_period(request)).order_by("started", "id")
        out = io.StringIO()
        writer = csv.writer(out)
        writer.writerow(CSV_COLUMNS)
        for f in flights.iterator(chunk_size=500):
            writer.writerow(
                [
                    f.pk,
                    f.vehicle.name,
                    f.pilot_name,
                    _utc(f.started),
                    _utc(f.ended),
                    "" if f.duration_s is None else f"{f.duration_s / 60:.2f}",
                    "" if f.distance_m is None else f"{f.distance_m / 1000:.3f}",
                    "" if f.max_alt_m is None else f"{f.max_alt_m:.1f}",
                    f.battery_name,
                    _number(f.battery_start_pct),
                    _number(f.battery_end_pct),
                    f.tasks_served,
                    "; ".join(str(c.get("name", "")) for c in f.customers),
                    f.get_ended_how_display() if f.ended_how else "in flight",
                ]
            )
        response = HttpResponse(out.getvalue(), content_type=f"{CSV_TYPE}; charset=utf-8")
        response["Content-Disposition"] = 'attachment; filename="flights.csv"'
        return response


def _utc(moment: dt.datetime | None) -> str:
    return "" if moment is None else moment.astimezone(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _number(value: float | None) -> str:
    return "" if value is None else f"{value:g}"
