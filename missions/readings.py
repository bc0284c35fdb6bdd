"""Camera readings inside JSON values (task readings, storage values): finding the images they
reference and rewriting those references; and a VV's readings as flat rows (``reading_rows``,
for the CSV, GeoJSON and KML downloads). Plain Python, no Django.

A camera reading is a dict with ``"kind": "camera"`` and an ``"image"`` reference: a path
under MEDIA_ROOT such as ``readings/ab/abcdef....png`` (see ``vvm_worker/sensing.py``).
Readings may sit anywhere in a value: in lists, in dicts, nested.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Any, TypeGuard

# Image file names as the platform makes them (content hash and extension); anything else in
# a URL is refused before a lookup.
IMAGE_FILE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,199}$")


def is_camera_reading(value: object) -> TypeGuard[dict[str, Any]]:
    """Whether a JSON value is one camera reading with an image reference."""
    return (
        isinstance(value, dict)
        and value.get("kind") == "camera"
        and isinstance(value.get("image"), str)
        and bool(value["image"])
    )


def image_file(reference: str) -> str:
    """The file name of an image reference (its basename), as the REST API names images."""
    return PurePosixPath(reference).name


def image_references(value: Any) -> Iterator[str]:
    """Every image reference of the camera readings in a JSON value, in document order."""
    if is_camera_reading(value):
        yield value["image"]
    elif isinstance(value, dict):
        for item in value.values():
            yield from image_references(item)
    elif isinstance(value, list):
        for item in value:
            yield from image_references(item)


def map_camera_readings(value: Any, fn: Callable[[dict[str, Any]], dict[str, Any]]) -> Any:
    """A copy of a JSON value with each camera reading replaced by ``fn(a copy of it)``."""
    if is_camera_reading(value):
        return fn(dict(value))
    if isinstance(value, dict):
        return {k: map_camera_readings(v, fn) for k, v in value.items()}
    if isinstance(value, list):
        return [map_camera_readings(v, fn) for v in value]
    return value


# --- readings as rows: what readings.csv and readings.geojson hold ---------------------------


@dataclass(frozen=True)
class ReadingRow:
    """One reading of a VV's task, flat: a row of ``readings.csv``, a feature of
    ``readings.geojson``, a placemark of ``track.kml``.

    ``time`` is the reading's own (ISO 8601 UTC); ``lat``, ``lng``, ``alt`` where it was taken
    (degrees, metres above ground; None when the reading does not say); ``value`` a number for
    a scalar sensor, the picture's address for a camera (as the caller names it), the fix as
    ``"lat, lng, alt"`` for a GPS; ``task_q`` and ``task_index`` the task's ``q`` and ``index``
    as ``GET /api/v1/vvs/{id}/tasks/`` shows them.
    """

    time: str
    lat: float | None
    lng: float | None
    alt: float | None
    sensor: str
    kind: str
    value: float | int | str | None
    unit: str
    task_q: int
    task_index: int


# A task's readings as the database keeps them: (q, index, readings).
TaskReadings = tuple[int, int, Any]


def reading_rows(
    tasks: Iterable[TaskReadings], *, picture: Callable[[str], str]
) -> list[ReadingRow]:
    """Every reading of these tasks as a row, in the order they were taken (a batch's tasks
    may be served in any order), a task's readings in the order of its sensors.

    ``picture`` turns a camera reading's image reference into the value the row shows (a URL,
    a file in a zip). Entries that are no reading (not a dict) are left out.
    """
    rows: list[tuple[tuple[int, int], int, ReadingRow]] = []
    for q, index, readings in tasks:
        for reading in readings if isinstance(readings, list) else ():
            if not isinstance(reading, dict):
                continue
            row = _row(reading, q, index, picture)
            rows.append((_moment(row.time), len(rows), row))
    rows.sort(key=lambda item: (item[0], item[1]))
    return [row for _, _, row in rows]


def _row(reading: dict[str, Any], q: int, index: int, picture: Callable[[str], str]) -> ReadingRow:
    where = reading.get("position")
    where = where if isinstance(where, dict) else {}
    kind = str(reading.get("kind") or "")
    value: float | int | str | None
    if is_camera_reading(reading):
        value = picture(reading["image"])
    elif kind == "gps" and all(_is_number(reading.get(k)) for k in ("lat", "lng", "alt")):
        value = f"{reading['lat']}, {reading['lng']}, {reading['alt']}"
    else:
        found = reading.get("value")
        value = found if _is_number(found) or isinstance(found, str) else None
    return ReadingRow(
        time=str(reading.get("time") or ""),
        lat=_number_or_none(where.get("lat")),
        lng=_number_or_none(where.get("lng")),
        alt=_number_or_none(where.get("alt")),
        sensor=str(reading.get("sensor") or ""),
        kind=kind,
        value=value,
        unit=str(reading.get("unit") or ""),
        task_q=q,
        task_index=index,
    )


def _is_number(value: object) -> TypeGuard[float | int]:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number_or_none(value: object) -> float | None:
    return float(value) if _is_number(value) else None


def reading_time_ms(time: object) -> int | None:
    """A reading's ``time`` (ISO 8601, UTC) as Unix epoch milliseconds; None when it is no
    such time."""
    if not isinstance(time, str):
        return None
    try:
        moment = dt.datetime.fromisoformat(time)
    except ValueError:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=dt.UTC)  # the platform writes UTC
    return round(moment.timestamp() * 1000)


def _moment(time: str) -> tuple[int, int]:
    """A sort key of a reading's time: readings without a readable time come last."""
    ms = reading_time_ms(time)
    return (1, 0) if ms is None else (0, ms)
