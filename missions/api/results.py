"""A VV's results as files: one zip with what the VV endpoints show and its pictures, and its
readings as CSV, GeoJSON and (with its flown track) KML, files that spreadsheets and GIS tools
open as they are."""

from __future__ import annotations

import csv
import io
import json
import logging
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterable, Sequence
from typing import IO, Any
from xml.etree import ElementTree as ET

from django.core.files.storage import default_storage
from django.utils.text import slugify
from rest_framework.request import Request

from missions.api.serializers import (
    LogEntryOutSerializer,
    StaffTaskOutSerializer,
    TaskOutSerializer,
    VVSerializer,
    platform_time,
)
from missions.models import TaskStatus, VirtualVehicle
from missions.readings import ReadingRow, image_file, map_camera_readings, reading_rows
from missions.selectors import (
    vv_image_references_for_user,
    vv_log_for_user,
    vv_storage_for_user,
    vv_tasks_for_user,
    vv_track_for_user,
)

logger = logging.getLogger("cpcc.api")

IMAGES_DIR = "images"
# Results are built in memory up to this size, in a temporary file beyond.
SPOOL_BYTES = 32 * 1024 * 1024

README = """\
Results of the virtual vehicle {name} ({id}).

vv.json           the VV as GET /api/v1/vvs/{id}/ shows it
storage.json      its storage, {{key: value}}; a camera reading's "image" names its file in images/
tasks.json        its tasks as GET /api/v1/vvs/{id}/tasks/ shows them, images as in storage.json
readings.csv      every reading of its tasks, one a row, in the order they were taken: time (UTC),
                  latitude, longitude, altitude_m (above ground), sensor, kind, value, unit,
                  task_q, task_index; a camera's value names its file in images/
readings.geojson  the same readings as a GeoJSON FeatureCollection of points ([lng, lat, alt])
track.kml         where it flew (a line with altitudes) and a placemark per reading, for
                  Google Earth and GIS tools
log.txt           its log: time, level, message
images/           every picture its readings took
"""

# The columns of readings.csv, and the properties of a readings.geojson feature (less the
# position, which is its geometry).
READINGS_COLUMNS = (
    "time", "latitude", "longitude", "altitude_m", "sensor", "kind", "value", "unit", "task_q",
    "task_index",
)  # fmt: skip
KML_NS = "http://www.opengis.net/kml/2.2"


def results_filename(vv: VirtualVehicle) -> str:
    """The name a results download is saved under: the VV's name and the start of its id."""
    return download_filename(vv, "results.zip")


def download_filename(vv: VirtualVehicle, what: str) -> str:
    """The name a download of the VV is saved under: its name, the start of its id and what
    the file is (``readings.csv``)."""
    return f"{slugify(vv.name) or 'vv'}-{str(vv.pk)[:8]}-{what}"


def vv_reading_rows(
    *, request: Request, vv: VirtualVehicle, picture: Callable[[str], str]
) -> list[ReadingRow]:
    """Every reading of the VV's tasks as a row (``reading_rows``); ``picture`` names a camera
    reading's picture. The caller has checked that the user may see the VV."""
    tasks = vv_tasks_for_user(user=request.user, vv_id=vv.pk)  # type: ignore[arg-type]
    done = tasks.filter(status=TaskStatus.DONE, readings__isnull=False)
    return reading_rows(done.values_list("q", "index", "readings").iterator(), picture=picture)


def readings_csv(rows: Iterable[ReadingRow]) -> str:
    """The rows as CSV (RFC 4180) with a header row of ``READINGS_COLUMNS``; an unknown
    position or value is an empty cell."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(READINGS_COLUMNS)
    for row in rows:
        writer.writerow(
            "" if cell is None else cell
            for cell in (
                row.time, row.lat, row.lng, row.alt, row.sensor, row.kind, row.value, row.unit,
                row.task_q, row.task_index,
            )
        )  # fmt: skip
    return out.getvalue()


def readings_geojson(rows: Iterable[ReadingRow]) -> dict[str, Any]:
    """The rows as a GeoJSON FeatureCollection (RFC 7946): a Point feature per reading at
    ``[lng, lat, alt]`` (alt in metres above ground, left out when unknown; no geometry when
    the reading has no position), its properties the other columns of readings.csv."""
    return {"type": "FeatureCollection", "features": [_feature(row) for row in rows]}


def _feature(row: ReadingRow) -> dict[str, Any]:
    geometry = None
    if row.lat is not None and row.lng is not None:
        where = [row.lng, row.lat] if row.alt is None else [row.lng, row.lat, row.alt]
        geometry = {"type": "Point", "coordinates": where}
    properties = {
        "time": row.time,
        "sensor": row.sensor,
        "kind": row.kind,
        "value": row.value,
        "unit": row.unit,
        "task_q": row.task_q,
        "task_index": row.task_index,
    }
    return {"type": "Feature", "geometry": geometry, "properties": properties}


def track_kml(
    *,
    name: str,
    track: Sequence[tuple[str | None, float, float, float]],
    rows: Iterable[ReadingRow],
) -> bytes:
    """A KML 2.2 document of a VV's flight: its track (``(time, lat, lng, alt)`` points, alt
    in metres above ground) as a line with altitudes, and a placemark per reading with its
    time, value and unit. UTF-8 bytes with an XML declaration."""
    ET.register_namespace("", KML_NS)
    kml = ET.Element(_kml("kml"))
    document = ET.SubElement(kml, _kml("Document"))
    _text(document, "name", name)
    if len(track) >= 2:
        flown = ET.SubElement(document, _kml("Placemark"))
        _text(flown, "name", "Track")
        times = [t for t, *_ in track if t]
        if times:
            span = ET.SubElement(flown, _kml("TimeSpan"))
            _text(span, "begin", times[0])
            _text(span, "end", times[-1])
        line = ET.SubElement(flown, _kml("LineString"))
        _text(line, "altitudeMode", "relativeToGround")
        _text(line, "coordinates", " ".join(f"{lng},{lat},{alt}" for _, lat, lng, alt in track))
    readings = ET.SubElement(document, _kml("Folder"))
    _text(readings, "name", "Readings")
    for row in rows:
        if row.lat is None or row.lng is None:
            continue
        mark = ET.SubElement(readings, _kml("Placemark"))
        value = "" if row.value is None else f" {row.value}"
        _text(mark, "name", f"{row.sensor}:{value}" + (f" {row.unit}" if row.unit else ""))
        if row.time:
            _text(ET.SubElement(mark, _kml("TimeStamp")), "when", row.time)
        data = ET.SubElement(mark, _kml("ExtendedData"))
        for key, cell in (
            ("sensor", row.sensor), ("kind", row.kind), ("value", row.value), ("unit", row.unit),
            ("task_q", row.task_q), ("task_index", row.task_index),
        ):  # fmt: skip
            field = ET.SubElement(data, _kml("Data"), name=key)
            _text(field, "value", "" if cell is None else str(cell))
        point = ET.SubElement(mark, _kml("Point"))
        _text(point, "altitudeMode", "relativeToGround")
        _text(point, "coordinates", f"{row.lng},{row.lat},{row.alt or 0.0}")
    return ET.tostring(kml, encoding="UTF-8", xml_declaration=True)  # type: ignore[no-any-return]


def _kml(tag: str) -> str:
    return f"{{{KML_NS}}}{tag}"


def _text(parent: ET.Element, tag: str, text: str) -> None:
    ET.SubElement(parent, _kml(tag)).text = text


def vv_track_kml(*, request: Request, vv: VirtualVehicle, rows: Iterable[ReadingRow]) -> bytes:
    """``track_kml`` of the VV: its track as the map keeps it, times in UTC."""
    points = vv_track_for_user(user=request.user, vv_id=vv.pk)  # type: ignore[arg-type]
    track = [
        (platform_time(vv, t_s), lat, lng, alt)
        for t_s, lat, lng, alt in points.values_list("t_s", "lat", "lng", "alt").iterator()
    ]
    return track_kml(name=vv.name, track=track, rows=rows)


def build_results_zip(*, request: Request, vv: VirtualVehicle) -> IO[bytes]:
    """Write the VV's results zip and return it, rewound: ``vv.json``, ``storage.json``,
    ``tasks.json``, ``readings.csv``, ``readings.geojson``, ``track.kml``, ``log.txt``,
    ``README.txt`` and ``images/<file>`` for every picture.

    The caller has checked that the user may see the VV; the selectors check it again.
    """
    user = request.user
    context = {"request": request}
    known = vv_image_references_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]

    def in_zip(reading: dict[str, Any]) -> dict[str, Any]:
        reading.pop("image_url", None)
        if reading["image"] in known:
            reading["image"] = f"{IMAGES_DIR}/{image_file(reading['image'])}"
        return reading

    storage = {
        doc.key: map_camera_readings(doc.value, in_zip)
        for doc in vv_storage_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    }
    task_serializer = StaffTaskOutSerializer if user.is_staff else TaskOutSerializer
    tasks = [
        {**task, "readings": map_camera_readings(task["readings"], in_zip)}
        for task in task_serializer(
            vv_tasks_for_user(user=user, vv_id=vv.pk),  # type: ignore[arg-type]
            many=True,
            context=context,
        ).data
    ]
    log = LogEntryOutSerializer(
        vv_log_for_user(user=user, vv_id=vv.pk),  # type: ignore[arg-type]
        many=True,
        context=context,
    ).data
    rows = vv_reading_rows(
        request=request, vv=vv, picture=lambda reference: f"{IMAGES_DIR}/{image_file(reference)}"
    )

    out = tempfile.SpooledTemporaryFile(max_size=SPOOL_BYTES)  # noqa: SIM115 (returned open)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("README.txt", README.format(name=vv.name, id=vv.pk))
        archive.writestr("vv.json", _json(VVSerializer(vv, context=context).data))
        archive.writestr("storage.json", _json(storage))
        archive.writestr("tasks.json", _json(tasks))
        archive.writestr("readings.csv", readings_csv(rows))
        archive.writestr("readings.geojson", _json(readings_geojson(rows)))
        archive.writestr("track.kml", vv_track_kml(request=request, vv=vv, rows=rows))
        archive.writestr(
            "log.txt", "".join(f"{e['at']} {e['level']} {e['message']}\n" for e in log)
        )
        for reference in sorted(known):
            if not default_storage.exists(reference):
                logger.warning(
                    "image of a reading is missing", extra={"vv": str(vv.pk), "image": reference}
                )
                continue
            info = zipfile.ZipInfo(f"{IMAGES_DIR}/{image_file(reference)}")
            info.compress_type = zipfile.ZIP_STORED  # PNG and JPEG are compressed already
            with default_storage.open(reference, "rb") as src, archive.open(info, "w") as dst:
                shutil.copyfileobj(src, dst)
    out.seek(0)
    return out  # type: ignore[return-value]


def _json(data: Any) -> str:
    return json.dumps(data, indent=2, ensure_ascii=False, default=str) + "\n"
