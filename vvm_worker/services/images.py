"""The host's side of ``VV.image.*``: find the picture a VV names, check that it is its
customer's and that the VV received it, and answer the call with ``vvm_worker.imaging`` (a new
picture is kept under MEDIA_ROOT and counts against the VV's storage quota).

A picture is a customer's (``Picture``) once one of its VVs received it in a task's readings
(``pictures_received``) or made it (crop, resize); a message hands a picture only to another VV
of the same customer: a reference another customer sends names nothing usable.

The caller (a VV's step, ``vvs``) charges the CPU time around ``image_call`` to the VV and
turns ``ImageCallError`` into the program's ``ImageError``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from typing import Any

from django.core.files.storage import default_storage
from django.db.models import TextField
from django.db.models.functions import Cast

from missions.models import JournalEntry, Picture, VirtualVehicle
from vvm_worker import imaging
from vvm_worker.runtime import Limits
from vvm_worker.sensing import image_reference, save_image

# The platform's reference to a picture it keeps (``sensing.save_image``): the folder is the
# first two digits of the name, so nothing else under MEDIA_ROOT can be named.
REFERENCE = re.compile(r"readings/([0-9a-f]{2})/\1[0-9a-f]{30}\.(?:png|jpg)")

# The source picture's fields a new picture carries on (the reading it came from).
SOURCE_FIELDS = ("sensor", "time", "position")


class ImageCallError(ValueError):
    """An image call the host cannot answer; the message starts with the call as the program
    wrote it and is the program's ImageError."""


def image_call(
    *, vv: VirtualVehicle, op: str, args: Mapping[str, Any], limits: Limits
) -> dict[str, Any] | float:
    """Answer the VV's image call ``op`` ("image.stats", "image.fraction", "image.crop" or
    "image.resize") with the pending request's ``args``.

    Returns what the program gets: stats' object, fraction's number, or for crop and resize
    the new picture ``{sensor, kind, time, position, image, width, height, format}`` (``sensor``,
    ``time`` and ``position`` copied from ``args["source"]`` when it has them), which is the
    VV's customer's from now on and whose bytes count against the VV's storage quota
    (``limits.storage_bytes``, with what its storage holds: ``VirtualVehicle.picture_bytes``).
    Raises ImageCallError for a picture the VV has not received or that is not its customer's
    (or that does not exist), one that cannot be read, an argument the picture does not fit,
    or a new picture the quota has no room for.
    """
    call = _call_text(op, args)
    try:
        data = _picture_bytes(vv, args.get("picture"))
        if data is None:
            raise ImageCallError(f"{call}: not a picture this VV has received")
        if op == "image.stats":
            return imaging.stats(data, _optional_region(args))
        if op == "image.fraction":
            return imaging.fraction(data, args.get("ranges"), _optional_region(args))
        if op == "image.crop":
            picture = imaging.crop(data, imaging.Region.from_json(args.get("region")))
        else:
            picture = imaging.resize(data, args.get("width"), args.get("height"))
    except imaging.ImagingError as error:
        raise ImageCallError(f"{call}: {error}") from None
    _count_made(vv, picture.data, limits, call)
    return _new_picture(picture, args.get("source"))


def pictures_received(*, vv: VirtualVehicle, readings: list[Any]) -> None:
    """The pictures of a task's camera readings, answered to ``vv``, are its customer's."""
    references = {
        image
        for reading in readings
        if isinstance(reading, Mapping)
        and isinstance(image := reading.get("image"), str)
        and REFERENCE.fullmatch(image)
    }
    if references:
        Picture.objects.bulk_create(
            [
                Picture(customer_id=vv.customer_id, reference=reference, vv=vv)
                for reference in sorted(references)
            ],
            ignore_conflicts=True,  # (the customer had it already)
        )


def _count_made(vv: VirtualVehicle, data: bytes, limits: Limits, call: str) -> None:
    """Make the new picture of these bytes the VV's customer's, counted against the VV's
    storage quota; ImageCallError when the quota has no room for it. A picture the customer
    has already (the same content) takes nothing more."""
    reference = image_reference(data, "png")
    if Picture.objects.filter(customer_id=vv.customer_id, reference=reference).exists():
        return
    size = len(data)
    used = vv.storage_bytes + vv.picture_bytes + size
    if used > limits.storage_bytes:
        raise ImageCallError(
            f"{call}: the new picture's {size:,} bytes would bring this VV's storage and "
            f"pictures to {used:,} bytes, more than the {limits.storage_bytes:,} allowed "
            "(quota: storage bytes)"
        )
    Picture.objects.bulk_create(
        [Picture(customer_id=vv.customer_id, reference=reference, vv=vv, made=True, bytes=size)],
        ignore_conflicts=True,  # (another VV of the customer made the same one just now)
    )
    vv.picture_bytes += size


def _optional_region(args: Mapping[str, Any]) -> imaging.Region | None:
    """stats' and fraction's region: null for the whole picture."""
    value = args.get("region")
    return None if value is None else imaging.Region.from_json(value)


def _call_text(op: str, args: Mapping[str, Any]) -> str:
    """The call as the program wrote it, the start of every error message."""
    if op == "image.stats":
        arguments = "picture" if args.get("region") is None else "picture, region"
    elif op == "image.fraction":
        arguments = "picture, ranges" if args.get("region") is None else "picture, ranges, region"
    elif op == "image.crop":
        arguments = "picture, region"
    elif op == "image.resize":
        arguments = "picture, width, height"
    else:
        raise ImageCallError(f"VV.{op}: not an image call")
    return f"VV.{op}({arguments})"


def _picture_bytes(vv: VirtualVehicle, reference: object) -> bytes | None:
    """The picture's bytes, or None unless it is one the platform keeps as the VV's customer's
    and the VV's journal holds it (a reading, a new picture or a message it received): a VV
    uses no other picture."""
    if not isinstance(reference, str) or not REFERENCE.fullmatch(reference):
        return None
    if not Picture.objects.filter(customer_id=vv.customer_id, reference=reference).exists():
        return None
    quoted = json.dumps(reference)  # the whole JSON string, not a part of a longer one
    texts = (
        JournalEntry.objects.filter(vv_id=vv.pk)
        .annotate(text=Cast("entry", output_field=TextField()))
        .filter(text__contains=quoted)
        .values_list("text", flat=True)
    )
    # SQLite's LIKE ignores case: the exact text is checked here.
    if not any(quoted in text for text in texts):  # (no server-side cursor: pipelined)
        return None
    try:
        with default_storage.open(reference, "rb") as file:
            return bytes(file.read())
    except OSError:  # kept in the journal, but gone from MEDIA_ROOT
        return None


def _new_picture(picture: imaging.Picture, source: object) -> dict[str, Any]:
    """The picture object crop and resize return, in a camera reading's field order."""
    copied = source if isinstance(source, Mapping) else {}
    result: dict[str, Any] = {}
    if "sensor" in copied:
        result["sensor"] = copied["sensor"]
    result["kind"] = "camera"
    for name in SOURCE_FIELDS[1:]:
        if name in copied:
            result[name] = copied[name]
    result.update(
        image=save_image(picture.data, "png"),
        width=picture.width,
        height=picture.height,
        format="png",
    )
    return result
