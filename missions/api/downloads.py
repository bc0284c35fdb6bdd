"""A VV's readings as files people open as they are: ``readings.csv`` for spreadsheets,
``readings.geojson`` for maps and GIS tools and ``track.kml`` (where it flew, and its readings)
for Google Earth (DESIGN.md section 9). Built by ``missions.api.results``, which also puts them
in the results zip.

Kept apart from ``views.py``, which imports ``results.py`` for the zip: these views need its
error handling and results.py's builders, so either module holding them would import the
other.
"""

from __future__ import annotations

import json
from typing import Any

from django.http import HttpResponse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiResponse, extend_schema
from rest_framework import generics
from rest_framework.request import Request
from rest_framework.serializers import BaseSerializer

from cpcc_site.api import DetailSerializer, FileOrJSONNegotiation
from missions.api.results import (
    READINGS_COLUMNS,
    download_filename,
    readings_csv,
    readings_geojson,
    vv_reading_rows,
    vv_track_kml,
)
from missions.api.serializers import image_url
from missions.api.views import NOT_FOUND, VV_ID, VVErrorsMixin
from missions.models import VirtualVehicle
from missions.readings import ReadingRow, image_file
from missions.selectors import vv_get_for_user

GEOJSON_TYPE = "application/geo+json"
CSV_TYPE = "text/csv"
KML_TYPE = "application/vnd.google-earth.kml+xml"

READING_COLUMNS_TEXT = (
    "`time` (the reading's, ISO 8601 UTC), `latitude` and `longitude` (degrees) and "
    "`altitude_m` (metres above ground) where it was taken, `sensor` (the SDC name), `kind` "
    "(`scalar`, `gps`, `camera`), `value` (a number for a scalar sensor; the URL of the "
    "picture for a camera, as `image_url` in the tasks; the fix as `lat, lng, alt` for a GPS), "
    "`unit`, and `task_q` and `task_index`, the task's `q` and `index` as "
    "`GET /api/v1/vvs/{id}/tasks/` shows them"
)

# What readings.geojson holds, for the schema: a FeatureCollection of Points (RFC 7946).
_NUMBER = {"type": "number"}
_FEATURE = {
    "type": "object",
    "required": ["type", "geometry", "properties"],
    "properties": {
        "type": {"type": "string", "enum": ["Feature"]},
        "geometry": {
            "type": "object",
            "nullable": True,
            "description": "Where the reading was taken (null: the reading does not say).",
            "required": ["type", "coordinates"],
            "properties": {
                "type": {"type": "string", "enum": ["Point"]},
                "coordinates": {
                    "type": "array",
                    "items": _NUMBER,
                    "minItems": 2,
                    "maxItems": 3,
                    "description": "[longitude, latitude, altitude in metres above ground]",
                },
            },
        },
        "properties": {
            "type": "object",
            "required": ["time", "sensor", "kind", "value", "unit", "task_q", "task_index"],
            "properties": {
                "time": {"type": "string", "description": "ISO 8601, UTC."},
                "sensor": {"type": "string"},
                "kind": {"type": "string"},
                "value": {
                    "nullable": True,
                    "oneOf": [_NUMBER, {"type": "string"}],
                    "description": "A number, a picture's URL or a GPS fix `lat, lng, alt`.",
                },
                "unit": {"type": "string"},
                "task_q": {"type": "integer"},
                "task_index": {"type": "integer"},
            },
        },
    },
}
GEOJSON_SCHEMA = {
    "type": "object",
    "required": ["type", "features"],
    "properties": {
        "type": {"type": "string", "enum": ["FeatureCollection"]},
        "features": {"type": "array", "items": _FEATURE},
    },
}


class _ReadingsDownload(VVErrorsMixin, generics.GenericAPIView):  # type: ignore[type-arg]
    """One of the VV's readings files: the caller's own VV (another customer's answers 404).
    A camera reading's value is the URL of its picture, as in the tasks."""

    content_negotiation_class = FileOrJSONNegotiation
    suffix = ""
    content_type = ""

    def get_serializer_class(self) -> type[BaseSerializer[Any]]:
        return DetailSerializer  # only errors are JSON here

    def body(self, vv: VirtualVehicle, rows: list[ReadingRow]) -> str | bytes:
        raise NotImplementedError

    def get(self, request: Request, id: str) -> HttpResponse:
        vv: VirtualVehicle = vv_get_for_user(user=request.user, vv_id=id)  # type: ignore[arg-type]
        context = {"request": request}
        rows = vv_reading_rows(
            request=request,
            vv=vv,
            picture=lambda reference: image_url(context, vv.pk, image_file(reference)),
        )
        response = HttpResponse(
            self.body(vv, rows), content_type=f"{self.content_type}; charset=utf-8"
        )
        filename = download_filename(vv, self.suffix)
        response["Content-Disposition"] = f'attachment; filename="{filename}"'
        return response


@extend_schema(
    parameters=[VV_ID],
    responses={
        (200, CSV_TYPE): OpenApiResponse(
            OpenApiTypes.STR, description="CSV with a header row, one reading a row."
        ),
        **NOT_FOUND,
    },
    description="Every reading of the VV's tasks as CSV (RFC 4180, UTF-8), in the order they "
    f"were taken. The columns: {', '.join(READINGS_COLUMNS)}: {READING_COLUMNS_TEXT}. "
    "An unknown position or value is an empty cell. The same file is in results.zip, where a "
    "camera's value names its file in the zip's `images/`.",
)
class VVReadingsCSVView(_ReadingsDownload):
    """The VV's readings as CSV, one reading a row."""

    suffix = "readings.csv"
    content_type = CSV_TYPE

    def body(self, vv: VirtualVehicle, rows: list[ReadingRow]) -> str:
        return readings_csv(rows)


@extend_schema(
    parameters=[VV_ID],
    responses={
        (200, GEOJSON_TYPE): OpenApiResponse(
            GEOJSON_SCHEMA, description="A GeoJSON FeatureCollection of Points (RFC 7946)."
        ),
        **NOT_FOUND,
    },
    description="Every reading of the VV's tasks as a GeoJSON FeatureCollection (RFC 7946), "
    "in the order they were taken: a `Point` feature per reading at `[longitude, latitude, "
    "altitude]` where it was taken (altitude in metres above ground), with the properties "
    "`time`, `sensor`, `kind`, `value`, `unit`, `task_q` and `task_index` as in "
    "readings.csv: " + READING_COLUMNS_TEXT + ". The same file is in results.zip.",
)
class VVReadingsGeoJSONView(_ReadingsDownload):
    """The VV's readings as GeoJSON, a point per reading."""

    suffix = "readings.geojson"
    content_type = GEOJSON_TYPE

    def body(self, vv: VirtualVehicle, rows: list[ReadingRow]) -> str:
        return json.dumps(readings_geojson(rows), ensure_ascii=False)


@extend_schema(
    parameters=[VV_ID],
    responses={
        (200, KML_TYPE): OpenApiResponse(
            OpenApiTypes.STR, description="A KML 2.2 document (UTF-8)."
        ),
        **NOT_FOUND,
    },
    description="Where the VV flew and what it read, as KML 2.2 for Google Earth and GIS tools: "
    "its track as a `LineString` of `longitude,latitude,altitude` points in the order flown "
    "(altitude in metres above ground, `relativeToGround`) with the flight's `TimeSpan`, and a "
    '`Folder` "Readings" with a `Placemark` per reading that has a position, in the order '
    "they were taken: its time as a `TimeStamp`, its `sensor`, `kind`, `value`, `unit`, "
    "`task_q` and `task_index` as `ExtendedData` (as in readings.csv: a camera's value is the "
    "URL of its picture). The same file is in results.zip, where a camera's value names its "
    "file in the zip's `images/`.",
)
class VVTrackKMLView(_ReadingsDownload):
    """The VV's flown track and its readings as KML."""

    suffix = "track.kml"
    content_type = KML_TYPE

    def body(self, vv: VirtualVehicle, rows: list[ReadingRow]) -> bytes:
        return vv_track_kml(request=self.request, vv=vv, rows=rows)
