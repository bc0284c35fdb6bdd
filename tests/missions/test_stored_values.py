"""Whatever a VV may store reads back everywhere: the deepest value the platform takes (100
levels, the limit of cpcc_site/json_depth.py), with a camera reading at its bottom, is shown by
the API's storage endpoints, the VV's page, storage.json, results.zip and the admin, to its
owner only; a deeper one never gets into the database."""

from __future__ import annotations

import io
import json
import zipfile

import pytest
from django.urls import reverse

from cpcc_site.json_depth import MAX_VALUE_DEPTH
from missions.models import StorageDocument, VVStatus
from tests.api_fixtures import token_client
from vvm_worker.services import vv_submit

# A value MAX_VALUE_DEPTH levels deep, objects and arrays by turns, a camera reading (itself an
# object) innermost; then one level more, which the store refuses.
DEEP = f"""
var v = {{kind: 'camera', sensor: 'Camera 640x480', image: 'readings/ab/abcdef.png', width: 1}};
for (var i = 1; i < {MAX_VALUE_DEPTH}; i++) v = (i % 2) ? [v] : {{k: v}};
VV.storage.store('deep', v);
try {{ VV.storage.store('deeper', [v]); }} catch (e) {{ VV.log('refused:', e.name); }}
"""


def depth(value: object) -> int:
    levels = 0
    while isinstance(value, list | dict):
        levels += 1
        value = value[0] if isinstance(value, list) else next(iter(value.values()))
    return levels


def innermost(value: object) -> dict:
    while not (isinstance(value, dict) and "kind" in value):
        value = value[0] if isinstance(value, list) else value["k"]
    return value


@pytest.fixture
def deep_vv(platform, ground_station, customer_a):
    vv = vv_submit(customer=customer_a, name="Deep", program=DEEP, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    return vv


def test_the_deepest_storable_value_is_stored_and_a_deeper_one_refused(deep_vv) -> None:
    assert list(deep_vv.storage.values_list("key", flat=True)) == ["deep"]
    assert depth(deep_vv.storage.get().value) == MAX_VALUE_DEPTH
    assert list(deep_vv.log.values_list("message", flat=True)) == ["refused: RangeError"]


def test_the_api_shows_the_deepest_value_to_its_owner(deep_vv, user_a, user_b) -> None:
    api = token_client(user_a)
    base = f"/api/v1/vvs/{deep_vv.pk}"
    listed = api.get(f"{base}/storage/")
    assert listed.status_code == 200
    value = listed.json()["results"][0]["value"]
    assert depth(value) == MAX_VALUE_DEPTH
    assert innermost(value)["image_url"].endswith("/images/abcdef.png")
    one = api.get(f"{base}/storage/deep/?format=json")
    assert one.status_code == 200 and depth(one.json()["value"]) == MAX_VALUE_DEPTH
    browsable = api.get(f"{base}/storage/deep/", HTTP_ACCEPT="text/html")
    assert browsable.status_code == 200
    results = api.get(f"{base}/results.zip")
    assert results.status_code == 200
    with zipfile.ZipFile(io.BytesIO(b"".join(results.streaming_content))) as packed:
        stored = json.loads(packed.read("storage.json"))
    assert depth(stored["deep"]) == MAX_VALUE_DEPTH
    other = token_client(user_b)
    for path in ("storage/", "storage/deep/", "results.zip"):
        assert other.get(f"{base}/{path}").status_code == 404, path


def test_the_pages_show_the_deepest_value_to_its_owner(client, deep_vv, user_a, user_b) -> None:
    client.force_login(user_a)
    page = client.get(reverse("vv-detail", args=[deep_vv.pk]))
    assert page.status_code == 200
    assert f"/api/v1/vvs/{deep_vv.pk}/images/abcdef.png" in page.text
    download = client.get(reverse("vv-storage-json", args=[deep_vv.pk]))
    assert download.status_code == 200 and depth(download.json()["deep"]) == MAX_VALUE_DEPTH
    client.force_login(user_b)
    assert client.get(reverse("vv-detail", args=[deep_vv.pk])).status_code == 404
    assert client.get(reverse("vv-storage-json", args=[deep_vv.pk])).status_code == 404


def test_the_admin_shows_the_deepest_value(client, deep_vv, staff, user_a) -> None:
    doc = StorageDocument.objects.get(vv=deep_vv)
    client.force_login(staff)
    assert client.get(reverse("admin:missions_storagedocument_changelist")).status_code == 200
    change = client.get(reverse("admin:missions_storagedocument_change", args=[doc.pk]))
    assert change.status_code == 200 and "abcdef.png" in change.text
    client.force_login(user_a)
    refused = client.get(reverse("admin:missions_storagedocument_change", args=[doc.pk]))
    assert refused.status_code == 302  # to the admin's login
