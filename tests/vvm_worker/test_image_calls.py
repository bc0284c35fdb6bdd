"""The host answers a VV's image calls only for pictures the VV received that are its customer's,
and keeps new ones, counted against the VV's storage quota."""

from __future__ import annotations

import importlib
import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from django.conf import settings
from PIL import Image

from missions.models import JournalEntry, Picture, VirtualVehicle
from vvm_worker import imaging
from vvm_worker.runtime import Limits
from vvm_worker.sensing import image_reference, save_picture
from vvm_worker.services import vv_submit
from vvm_worker.services.images import ImageCallError, image_call, pictures_received

PROGRAM = "VV.storage.store('started', true);"
GREEN = (20, 200, 40)
RED = (210, 30, 0)
LIMITS = Limits()  # 10 MB of storage
POSITION = {"lat": 48.1111, "lng": 12.8619, "alt": 50.0}


def half_green(width: int = 640, height: int = 480, fmt: str = "PNG") -> bytes:
    image = Image.new("RGB", (width, height), RED)
    image.paste(GREEN, (0, 0, width // 2, height))
    out = io.BytesIO()
    image.save(out, format=fmt)
    return out.getvalue()


def camera_reading(reference: str, width: int = 640, height: int = 480) -> dict[str, Any]:
    return {
        "sensor": "Camera",
        "kind": "camera",
        "time": "2025-05-01T10:00:00.000Z",
        "position": POSITION,
        "image": reference,
        "width": width,
        "height": height,
        "format": reference.rsplit(".", 1)[1],
    }


def receive(vv: VirtualVehicle, data: Any, kind: str = "done") -> None:
    """Append an answer to the VV's journal as a task's readings would come (its pictures its
    customer's from then on), or as another kind of answer (a message: "msg")."""
    seq = vv.journal_length
    JournalEntry.objects.create(vv=vv, seq=seq, entry={"q": seq, "k": kind, "t": 0, "data": data})
    if kind == "done" and isinstance(data, list):
        pictures_received(vv=vv, readings=data)
    vv.journal_length = seq + 1
    vv.save(update_fields=["journal_length"])


@pytest.fixture
def vv(customer_a, ground_station, vvm_factory) -> VirtualVehicle:
    return vv_submit(customer=customer_a, name="Photographer", program=PROGRAM, vvm=vvm_factory())


@pytest.fixture
def picture(vv) -> str:
    """A 640 x 480 picture, green on the left half, that the VV received in a reading."""
    reference = save_picture(half_green(), "png")
    receive(vv, [camera_reading(reference)])
    return reference


def test_stats_and_fraction_of_a_received_picture(vv, picture) -> None:
    result = image_call(
        limits=LIMITS, vv=vv, op="image.stats", args={"picture": picture, "region": None}
    )
    assert result == {
        "width": 640,
        "height": 480,
        "mean": {"r": 115.0, "g": 115.0, "b": 20.0},
        "std": {"r": 95.0, "g": 85.0, "b": 20.0},
    }
    green = {"g": [150, 255], "r": [0, 100]}
    args = {"picture": picture, "ranges": green, "region": None}
    assert image_call(limits=LIMITS, vv=vv, op="image.fraction", args=args) == 0.5
    left = {"x": 0, "y": 100, "width": 320, "height": 10}
    args = {"picture": picture, "ranges": green, "region": left}
    assert image_call(limits=LIMITS, vv=vv, op="image.fraction", args=args) == 1.0


def test_a_jpeg_picture_is_read_too(vv) -> None:
    reference = save_picture(half_green(fmt="JPEG"), "jpeg")
    assert reference.endswith(".jpg")
    receive(vv, [camera_reading(reference)])
    args = {"picture": reference, "ranges": {"g": [150, 255]}, "region": None}
    assert 0.45 < image_call(limits=LIMITS, vv=vv, op="image.fraction", args=args) < 0.55


def test_a_crop_is_kept_under_media_root_and_carries_the_source_reading(vv, picture) -> None:
    source = {"sensor": "Camera", "time": "2025-05-01T10:00:00.000Z", "position": POSITION}
    region = {"x": 300, "y": 10, "width": 40, "height": 20}
    result = image_call(
        limits=LIMITS,
        vv=vv,
        op="image.crop",
        args={"picture": picture, "region": region, "source": source},
    )
    assert isinstance(result, dict)
    assert result == {
        "sensor": "Camera",
        "kind": "camera",
        "time": "2025-05-01T10:00:00.000Z",
        "position": POSITION,
        "image": result["image"],
        "width": 40,
        "height": 20,
        "format": "png",
    }
    assert result["image"] != picture and result["image"].endswith(".png")
    kept = Path(settings.MEDIA_ROOT) / result["image"]
    expected = np.array([[GREEN] * 20 + [RED] * 20] * 20, dtype=np.uint8)
    assert np.array_equal(np.asarray(Image.open(kept).convert("RGB")), expected)
    # The crop's answer goes into the journal: from then on the VV may use the new picture.
    receive(vv, result)
    again = image_call(
        limits=LIMITS, vv=vv, op="image.stats", args={"picture": result["image"], "region": None}
    )
    assert again["mean"] == {"r": 115.0, "g": 115.0, "b": 20.0}


def test_a_resize_of_a_picture_without_a_source_has_only_the_picture_fields(vv, picture) -> None:
    result = image_call(
        limits=LIMITS,
        vv=vv,
        op="image.resize",
        args={"picture": picture, "width": 64, "height": 48, "source": {}},
    )
    assert isinstance(result, dict)
    assert set(result) == {"kind", "image", "width", "height", "format"}
    assert (result["width"], result["height"], result["format"]) == (64, 48, "png")
    kept = Image.open(Path(settings.MEDIA_ROOT) / result["image"])
    assert kept.size == (64, 48)


def test_a_region_beyond_the_picture_names_the_call_and_why(vv, picture) -> None:
    region = {"x": 600, "y": 0, "width": 100, "height": 10}
    with pytest.raises(ImageCallError) as error:
        image_call(
            limits=LIMITS, vv=vv, op="image.crop", args={"picture": picture, "region": region}
        )
    assert str(error.value) == (
        "VV.image.crop(picture, region): region.x + region.width = 700 is beyond the "
        "picture's width 640"
    )
    with pytest.raises(ImageCallError) as error:
        image_call(
            limits=LIMITS,
            vv=vv,
            op="image.fraction",
            args={"picture": picture, "ranges": {"q": [0, 1]}, "region": None},
        )
    assert str(error.value) == (
        "VV.image.fraction(picture, ranges): ranges.q is not a channel: the channels are r, g and b"
    )
    with pytest.raises(ImageCallError) as error:
        image_call(
            limits=LIMITS,
            vv=vv,
            op="image.resize",
            args={"picture": picture, "width": 5000, "height": 10},
        )
    assert str(error.value) == (
        "VV.image.resize(picture, width, height): width = 5000 must be between 1 and 4096"
    )


def refused(vv: VirtualVehicle, reference: object, region: Any = None) -> str:
    with pytest.raises(ImageCallError) as error:
        image_call(
            limits=LIMITS, vv=vv, op="image.stats", args={"picture": reference, "region": region}
        )
    return str(error.value)


def test_a_picture_the_vv_has_not_received_is_refused(vv, picture) -> None:
    kept_elsewhere = save_picture(half_green(320, 240), "png")
    assert (Path(settings.MEDIA_ROOT) / kept_elsewhere).is_file()
    assert (
        refused(vv, kept_elsewhere) == "VV.image.stats(picture): not a picture this VV has received"
    )
    # Named only inside a longer text is not received either.
    receive(vv, {"note": f"see {kept_elsewhere} later"})
    assert refused(vv, kept_elsewhere, {"x": 0, "y": 0, "width": 1, "height": 1}) == (
        "VV.image.stats(picture, region): not a picture this VV has received"
    )


def test_another_customers_picture_is_refused_like_a_missing_one(
    vv, customer_b, vvm_factory
) -> None:
    theirs = vv_submit(customer=customer_b, name="Other", program=PROGRAM, vvm=vvm_factory())
    reference = save_picture(half_green(100, 100), "png")
    receive(theirs, [camera_reading(reference, 100, 100)])
    assert image_call(
        limits=LIMITS, vv=theirs, op="image.stats", args={"picture": reference, "region": None}
    )
    missing = "readings/ab/ab" + "0" * 30 + ".png"
    receive(vv, [camera_reading(missing)])  # in the journal, but no such file
    wording = "VV.image.stats(picture): not a picture this VV has received"
    assert refused(vv, reference) == wording
    assert refused(vv, missing) == wording


@pytest.mark.parametrize(
    "reference",
    [
        "../../cpcc_site/settings.py",
        "readings/ab/cd0000000000000000000000000000000.png",  # folder not the name's start
        "readings/AB/AB000000000000000000000000000000.png",
        "readings/ab/ab000000000000000000000000000000.gif",
        "/readings/ab/ab000000000000000000000000000000.png",
        None,
        {"image": "readings/ab/ab000000000000000000000000000000.png"},
    ],
)
def test_a_reference_not_of_the_platforms_form_is_refused(vv, reference) -> None:
    receive(vv, [reference])
    assert refused(vv, reference) == "VV.image.stats(picture): not a picture this VV has received"


def test_an_unreadable_picture_in_the_journal_is_an_image_error(vv) -> None:
    reference = save_picture(b"not a picture", "png")
    receive(vv, [camera_reading(reference)])
    assert refused(vv, reference) == (
        "VV.image.stats(picture): picture: not a readable PNG or JPEG image"
    )


def test_another_customers_picture_named_in_a_message_is_refused(
    vv, customer_b, vvm_factory
) -> None:
    theirs = vv_submit(customer=customer_b, name="Other", program=PROGRAM, vvm=vvm_factory())
    reference = save_picture(half_green(100, 100), "png")
    receive(theirs, [camera_reading(reference, 100, 100)])
    # Customer A learned the reference (an image URL, an exported file) and sends it to its
    # own VV over the API: the VV has received it, but it is not its customer's picture.
    message = {"from": "", "id": 1, "value": {"picture": reference}, "sentAt": "2025-05-01T10:00Z"}
    receive(vv, message, kind="msg")
    wording = "VV.image.stats(picture): not a picture this VV has received"
    assert refused(vv, reference) == wording
    with pytest.raises(ImageCallError, match="not a picture this VV has received"):
        image_call(
            limits=LIMITS,
            vv=vv,
            op="image.crop",
            args={"picture": reference, "region": {"x": 0, "y": 0, "width": 1, "height": 1}},
        )
    # Another VV of customer B that got it in a message from its sister uses it.
    sister = vv_submit(customer=customer_b, name="Sister", program=PROGRAM, vvm=vvm_factory())
    receive(sister, {**message, "from": "Other"}, kind="msg")
    args = {"picture": reference, "region": None}
    assert image_call(limits=LIMITS, vv=sister, op="image.stats", args=args)["width"] == 100


def test_the_pictures_a_vv_makes_count_against_its_storage_quota(vv, picture) -> None:
    vv.storage_bytes = 1_000  # what its storage held after its last step
    limits = Limits(storage_bytes=5_000)
    source = (Path(settings.MEDIA_ROOT) / picture).read_bytes()
    made: list[int] = []
    error: ImageCallError | None = None
    for width in range(40, 400):
        args = {"picture": picture, "width": width, "height": 30, "source": {}}
        try:
            image_call(limits=limits, vv=vv, op="image.resize", args=args)
        except ImageCallError as refusal:
            error = refusal
            break
        made.append(width)
    assert error is not None
    assert 2 <= len(made) < 100
    kept = Picture.objects.filter(vv=vv, made=True)
    assert kept.count() == len(made)
    assert vv.picture_bytes == sum(kept.values_list("bytes", flat=True))
    assert 1_000 + vv.picture_bytes <= 5_000
    # The picture refused was not kept, and the message says what the quota counts.
    refused_width = made[-1] + 1
    new = imaging.resize(source, refused_width, 30).data
    assert not (Path(settings.MEDIA_ROOT) / image_reference(new, "png")).exists()
    used = 1_000 + vv.picture_bytes + len(new)
    assert str(error) == (
        f"VV.image.resize(picture, width, height): the new picture's {len(new):,} bytes would "
        f"bring this VV's storage and pictures to {used:,} bytes, more than the 5,000 allowed "
        "(quota: storage bytes)"
    )
    # A picture it made before takes nothing more when it makes it again.
    before = vv.picture_bytes
    args = {"picture": picture, "width": made[0], "height": 30, "source": {}}
    image_call(limits=limits, vv=vv, op="image.resize", args=args)
    assert vv.picture_bytes == before


def test_an_older_database_gives_customers_the_pictures_their_vvs_received(
    vv, customer_b, vvm_factory
) -> None:
    """The migration that brought pictures' owners finds them in the journals written before."""
    from django.apps import apps

    migration = importlib.import_module("missions.migrations.0012_pictures")
    theirs = vv_submit(customer=customer_b, name="Other", program=PROGRAM, vvm=vvm_factory())
    taken = save_picture(half_green(100, 100), "png")
    made = save_picture(half_green(10, 10), "png")
    foreign = save_picture(half_green(20, 20), "png")
    written = [
        (vv, "done", [camera_reading(taken, 100, 100)]),
        (vv, "ret", {"kind": "camera", "image": made, "width": 10, "height": 10}),
        (vv, "msg", {"from": "", "id": 1, "value": foreign, "sentAt": "2025-05-01T10:00Z"}),
        (theirs, "part", [camera_reading(foreign, 20, 20)]),
    ]
    for seq, (owner, kind, data) in enumerate(written):
        JournalEntry.objects.create(vv=owner, seq=seq, entry={"q": seq, "k": kind, "data": data})
    Picture.objects.all().delete()
    migration.find_pictures(apps, None)
    assert set(Picture.objects.values_list("customer_id", "reference", "made", "vv_id")) == {
        (vv.customer_id, taken, False, vv.pk),
        (vv.customer_id, made, True, vv.pk),
        (customer_b.pk, foreign, False, theirs.pk),
    }
    vv.refresh_from_db()
    assert vv.picture_bytes == (Path(settings.MEDIA_ROOT) / made).stat().st_size
