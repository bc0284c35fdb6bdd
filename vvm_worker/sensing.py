"""Turning a vehicle's sensor samples into readings a VV receives (DESIGN.md section 2).

A reading is ``{sensor, kind, time, position}`` plus ``value`` and ``unit`` for a scalar
sensor, ``lat``, ``lng``, ``alt`` (and ``satellites``, ``hdop``) for GPS, and ``image``,
``width``, ``height``, ``format`` for a camera. ``time`` is ISO 8601 UTC; ``image`` is a
reference to a file the platform keeps (a path under MEDIA_ROOT), never the bytes.
Readings never name the vehicle that took them.
"""

from __future__ import annotations

import datetime as dt
import hashlib
from collections.abc import Mapping, Sequence
from typing import Any

from django.core.files.base import ContentFile
from django.core.files.storage import default_storage

from fleet.driving import Sample, SensorFailure
from fleet.geo import Position
from fleet.simulation import SensorField, SensorSpec, render_camera
from fleet.simulation.sensors import SCALAR_QUANTITIES

IMAGE_DIR = "readings"


def sensor_spec(entry: Mapping[str, Any]) -> SensorSpec:
    return SensorSpec(
        name=str(entry["name"]),
        kind=str(entry["kind"]),
        unit=str(entry.get("unit") or ""),
        params=dict(entry.get("params") or {}),
    )


def iso_time(epoch_ms: int) -> str:
    moment = dt.datetime.fromtimestamp(epoch_ms / 1000, tz=dt.UTC)
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def image_reference(data: bytes, extension: str) -> str:
    """The reference ``save_image`` keeps an image of this content under."""
    digest = hashlib.sha256(data).hexdigest()
    return f"{IMAGE_DIR}/{digest[:2]}/{digest[:32]}.{extension}"


def save_image(data: bytes, extension: str) -> str:
    """Keep an image under MEDIA_ROOT, named by its content, and return its reference."""
    name = image_reference(data, extension)
    if not default_storage.exists(name):
        saved = default_storage.save(name, ContentFile(data))
        if saved != name:  # another process stored the same content at the same moment
            default_storage.delete(saved)
    return name


def save_picture(data: bytes, fmt: str) -> str:
    """``save_image`` for a camera's picture of this format ("png", "jpeg" or "jpg")."""
    return save_image(data, "jpg" if fmt.lower() in ("jpeg", "jpg") else "png")


def read_sensors(
    *,
    field: SensorField,
    sensors: Sequence[Mapping[str, Any]],
    position: Position,
    time_s: float,
    epoch_ms: int,
    battery_fraction: float | None = None,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """One reading per sensor, in the order asked, taken at ``position`` at ``time_s``."""
    readings = []
    for entry in sensors:
        spec = sensor_spec(entry)
        reading: dict[str, Any] = {
            "sensor": spec.name,
            "kind": spec.kind,
            "time": iso_time(epoch_ms),
            "position": {"lat": position.lat, "lng": position.lng, "alt": position.alt},
        }
        reading.update(field.sample(spec, position, time_s, battery_fraction=battery_fraction))
        if spec.kind == "camera":
            # The caption prints the reading's time (a simulation's clock counts from 0).
            image = render_camera(spec, position, time_s, seed=seed, epoch_s=epoch_ms / 1000)
            reading["image"] = save_picture(image, str(spec.params.get("format", "png")))
        readings.append(reading)
    return readings


def vehicle_reading(entry: Mapping[str, Any], sample: Sample) -> dict[str, Any]:
    """The reading of an SDC entry as the vehicle took it (its own time and position); a
    picture is kept under MEDIA_ROOT. SensorFailure for a picture the vehicle did not give."""
    spec = sensor_spec(entry)
    here = sample.position
    reading: dict[str, Any] = {
        "sensor": spec.name,
        "kind": spec.kind,
        "time": iso_time(sample.epoch_ms),
        "position": {"lat": here.lat, "lng": here.lng, "alt": here.alt},
        **sample.fields,
    }
    if spec.kind == "scalar":
        quantity = str(spec.params.get("quantity", "")).lower()
        reading["unit"] = spec.unit or SCALAR_QUANTITIES.get(quantity, "")
    elif spec.kind == "camera":
        if not sample.image:
            raise SensorFailure("the camera gave no picture", where=spec.name)
        fmt = str(sample.fields.get("format") or spec.params.get("format", "png"))
        reading["image"] = save_picture(sample.image, fmt)
    return reading
