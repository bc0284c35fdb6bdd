"""What hangs off one VV: storage, tasks, log, images and the results zip, from a mission
really flown in-process; the second customer gets 404 on every one of them."""

from __future__ import annotations

import io
import json
import urllib.parse
import zipfile

import pytest
from django.core.files.storage import default_storage
from PIL import Image
from rest_framework.pagination import PageNumberPagination

from missions.models import StorageDocument
from tests.api_fixtures import MISSION_KEYS
from vvm_worker.services import vv_submit

NO_SUCH_ID = "00000000-0000-0000-0000-000000000000"


def vv_url(vv, rest: str = "") -> str:
    return f"/api/v1/vvs/{vv.pk}/{rest}"


def storage_item_url(vv, key: str) -> str:
    return vv_url(vv, f"storage/{urllib.parse.quote(key, safe='')}/")


def with_image_url(vv, reading: dict) -> dict:
    """A stored camera reading as the API shows it: with the URL of its picture."""
    file = reading["image"].rsplit("/", 1)[-1]
    return {**reading, "image_url": f"http://testserver/api/v1/vvs/{vv.pk}/images/{file}"}


def camera_of(body: dict) -> dict:
    assert body["key"].endswith(".camera")
    return body["value"]


def test_every_vv_endpoint_answers_404_to_another_customer(mission, api_a, api_b) -> None:
    image = default_storage.path(mission.storage.get(key="p0.camera").value["image"])
    file = image.rsplit("/", 1)[-1]
    paths = [
        "",
        "storage/",
        "storage/p0.co2/",
        "storage/p0.camera/",
        "tasks/",
        "log/",
        "results.zip",
        f"images/{file}",
    ]
    for rest in paths:
        assert api_a.get(vv_url(mission, rest)).status_code == 200, rest
        refused = api_b.get(vv_url(mission, rest))
        assert refused.status_code == 404, rest
        missing = api_b.get(vv_url(mission, rest).replace(str(mission.pk), NO_SUCH_ID))
        assert refused.json() == missing.json(), "another customer's VV looks like a missing one"
    assert api_b.post(vv_url(mission, "cancel/")).status_code == 404


def test_storage_lists_keys_and_values_with_image_urls(mission, api_a) -> None:
    body = api_a.get(vv_url(mission, "storage/")).json()
    assert body["count"] == len(MISSION_KEYS)
    docs = {d["key"]: d for d in body["results"]}
    assert list(docs) == MISSION_KEYS
    assert docs["plain key"]["value"] == 42
    assert docs["p0.co2"]["value"]["unit"] == "ppm" and "image_url" not in docs["p0.co2"]["value"]
    assert docs["p0.co2"]["updated"].startswith("2025-01-01T00:")  # the readings' dates
    camera = docs["p0.camera"]["value"]
    file = camera["image"].rsplit("/", 1)[-1]
    assert camera["image_url"] == f"http://testserver/api/v1/vvs/{mission.pk}/images/{file}"
    nested = docs["all/readings"]["value"]
    assert nested["note"] == "nested"
    assert nested["points"][0]["image_url"] == camera["image_url"]
    assert nested["points"][1][0]["image_url"].endswith(".png")
    stored = StorageDocument.objects.get(vv=mission, key="p0.camera").value
    assert "image_url" not in stored, "the API must not change what the VV stored"


def test_storage_lists_are_paginated(mission, api_a, monkeypatch) -> None:
    monkeypatch.setattr(PageNumberPagination, "page_size", 4)
    first = api_a.get(vv_url(mission, "storage/")).json()
    assert len(first["results"]) == 4 and first["next"]
    second = api_a.get(first["next"]).json()
    keys = [d["key"] for d in first["results"] + second["results"]]
    assert keys == MISSION_KEYS and second["next"] is None


def test_a_page_of_storage_or_log_costs_the_same_statements_whatever_its_rows(
    mission, api_a, monkeypatch
) -> None:
    from django.db import connection
    from django.test.utils import CaptureQueriesContext

    api_a.get(vv_url(mission, "log/"))  # the token, remembered
    counted = {}
    for size in (1, 2):
        monkeypatch.setattr(PageNumberPagination, "page_size", size)
        for what in ("storage/", "log/"):
            with CaptureQueriesContext(connection) as seen:
                body = api_a.get(vv_url(mission, what)).json()
            assert len(body["results"]) == size
            counted[what, size] = len(seen.captured_queries)
    # The VV, the count, the page: none for each row (a row's VV is the one read first).
    assert counted["storage/", 1] == counted["storage/", 2] <= 3
    assert counted["log/", 1] == counted["log/", 2] <= 3


@pytest.mark.parametrize("key", ["p0.co2", "plain key", "all/readings"])
def test_one_storage_key_whatever_characters_it_has(mission, api_a, key) -> None:
    response = api_a.get(storage_item_url(mission, key))
    assert response.status_code == 200, response.content
    assert response.json()["key"] == key
    stored = mission.storage.get(key=key).value
    expected = stored
    if key == "all/readings":
        # What the VV stored, and each camera reading in it, however deep, says where its
        # picture is.
        expected = {
            "points": [
                with_image_url(mission, stored["points"][0]),
                [with_image_url(mission, stored["points"][1][0])],
            ],
            "note": "nested",
        }
    assert response.json()["value"] == expected


def test_keys_with_odd_characters_round_trip(mission, api_a) -> None:
    odd = ["a?b#c", "x%41y", "päth/with/slashes/", "..", "-.-", "two\nlines", " ", "k" * 128]
    for key in odd:
        StorageDocument.objects.create(vv=mission, key=key, value=key, size_bytes=1, updated_s=1)
    for key in odd:
        response = api_a.get(storage_item_url(mission, key))
        assert response.status_code == 200, key
        assert response.json()["value"] == key


def test_an_unknown_key_is_a_404_that_says_which(mission, api_a) -> None:
    response = api_a.get(storage_item_url(mission, "nope"))
    assert response.status_code == 404
    assert "'nope'" in response.json()["detail"]


def test_a_camera_reading_key_serves_the_picture_or_json_on_request(mission, api_a) -> None:
    picture = api_a.get(storage_item_url(mission, "p0.camera"))
    assert picture.status_code == 200
    assert picture["Content-Type"] == "image/png"
    image = Image.open(io.BytesIO(b"".join(picture.streaming_content)))
    assert image.size == (640, 480)
    as_json = api_a.get(storage_item_url(mission, "p0.camera") + "?format=json")
    assert as_json.status_code == 200
    assert as_json.json()["value"]["kind"] == "camera"
    assert as_json.json()["value"]["image_url"].startswith("http://testserver/")
    # A client that asks only for images still gets JSON errors, not a 406.
    missing = api_a.get(storage_item_url(mission, "nope"), HTTP_ACCEPT="image/png")
    assert missing.status_code == 404 and "nope" in missing.json()["detail"]


def test_an_image_url_serves_the_png(mission, api_a) -> None:
    url = api_a.get(storage_item_url(mission, "p1.camera") + "?format=json").json()["value"][
        "image_url"
    ]
    response = api_a.get(url, HTTP_ACCEPT="image/png")
    assert response.status_code == 200 and response["Content-Type"] == "image/png"
    assert Image.open(io.BytesIO(b"".join(response.streaming_content))).size == (640, 480)
    assert api_a.get(vv_url(mission, "images/nothing.png")).status_code == 404
    assert api_a.get(vv_url(mission, "images/..")).status_code == 404


def test_an_image_only_another_customers_reading_took_is_not_served(
    mission, platform, customer_b, api_b
) -> None:
    """A VV can store anything that looks like a camera reading, another customer's image
    reference included: only references its own task readings hold are served."""
    theirs = mission.storage.get(key="p0.camera").value["image"]
    forged = f"VV.storage.store('stolen', {{kind: 'camera', image: {json.dumps(theirs)}}});"
    vv_b = vv_submit(customer=customer_b, name="Forger", program=forged, vvm=platform.vvm)
    platform.drain()
    assert default_storage.exists(theirs)
    file = theirs.rsplit("/", 1)[-1]
    assert api_b.get(vv_url(vv_b, f"images/{file}")).status_code == 404
    assert api_b.get(storage_item_url(vv_b, "stolen")).status_code == 404


def test_tasks_show_positions_times_readings_and_rejections(mission, api_a, api_staff) -> None:
    body = api_a.get(vv_url(mission, "tasks/")).json()
    tasks = body["results"]
    assert body["count"] == 3
    assert [t["status"] for t in tasks] == ["rejected", "done", "done"]
    rejected, first, _ = tasks
    assert rejected["position"] == [10.0, 10.0, 50.0] and rejected["readings"] is None
    assert "outside every operation area" in rejected["message"]
    assert first["position"] == [48.1111, 12.8619, 50.0] and first["tolerance_m"] == 2.0
    assert first["sensors"] == ["Camera 640x480", "CO2"]
    assert first["requested"].startswith("2025-01-01T") and first["done"] > first["requested"]
    camera, co2 = first["readings"]
    assert camera["image_url"].endswith(camera["image"].rsplit("/", 1)[-1])
    assert co2["sensor"] == "CO2" and first["message"] == ""
    assert {"q", "index"} <= set(first)
    assert "vehicle" not in first and "Heli One" not in json.dumps(body)
    staff_view = api_staff.get(vv_url(mission, "tasks/")).json()["results"]
    assert [t["vehicle"] for t in staff_view] == [None, "Heli One", "Heli One"]


def test_the_log_has_times_levels_and_messages(mission, api_a) -> None:
    lines = api_a.get(vv_url(mission, "log/")).json()["results"]
    messages = [line["message"] for line in lines]
    assert "rejected: TaskRejectedError" in messages
    assert f"done: {len(MISSION_KEYS)} keys" in messages
    assert all(line["level"] and line["at"].startswith("2025-01-01T") for line in lines)


def test_results_zip_holds_everything_with_the_images(mission, api_a) -> None:
    response = api_a.get(vv_url(mission, "results.zip"))
    assert response.status_code == 200
    assert response["Content-Type"] == "application/zip"
    assert 'filename="survey-' in response["Content-Disposition"]
    archive = zipfile.ZipFile(io.BytesIO(b"".join(response.streaming_content)))
    names = set(archive.namelist())
    assert {"vv.json", "storage.json", "tasks.json", "log.txt"} <= names
    vv = json.loads(archive.read("vv.json"))
    assert vv == api_a.get(vv_url(mission)).json()
    storage = json.loads(archive.read("storage.json"))
    assert sorted(storage) == MISSION_KEYS
    pictures = [storage["p0.camera"]["image"], storage["p1.camera"]["image"]]
    assert storage["all/readings"]["points"][0]["image"] == pictures[0]
    images = sorted(n for n in names if n.startswith("images/"))
    assert sorted(pictures) == images and len(images) == 2
    for name in images:
        assert Image.open(io.BytesIO(archive.read(name))).size == (640, 480)
    tasks = json.loads(archive.read("tasks.json"))
    assert tasks[1]["readings"][0]["image"] in images
    assert "image_url" not in json.dumps(tasks) + json.dumps(storage)
    log = archive.read("log.txt").decode()
    assert "done: 6 keys" in log and log.startswith("2025-01-01T")
