"""Camera readings inside JSON values (task readings, storage values): finding the images they
reference and rewriting those references. Plain Python, no Django.

A camera reading is a dict with ``"kind": "camera"`` and an ``"image"`` reference: a path
under MEDIA_ROOT such as ``readings/ab/abcdef....png`` (see ``vvm_worker/sensing.py``).
Readings may sit anywhere in a value: in lists, in dicts, nested.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
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
