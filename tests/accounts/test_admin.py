"""Customers in the admin: quotas in plain words and units (sizes in MB, the allowed VVM-API
calls as boxes to tick), kept in bytes and as a JSON list as the API keeps them. Their API
tokens and webhooks: staff see them and may delete one (a token revoked at once, a webhook no
longer listened for), never add one or see a key or secret."""

from __future__ import annotations

import html
import re

import pytest
from django.urls import reverse
from rest_framework.test import APIClient

from accounts.models import ApiToken, Customer, Webhook
from accounts.services import api_token_create, webhook_create
from tests.admin_forms import form_as_shown
from vvm_worker.runtime import VVM_API_CALLS

pytestmark = pytest.mark.django_db


def _input_value(page: str, name: str) -> str:
    found = re.search(rf'<input type="number" name="{name}" value="([^"]*)"', page)
    assert found, f"no number input {name}"
    return found.group(1)


def test_the_customer_form_shows_sizes_in_mb_and_saves_them_in_bytes(
    client, staff, customer_a, customer_b
) -> None:
    assert (customer_a.storage_bytes, customer_a.heap_bytes) == (10_485_760, 67_108_864)
    client.force_login(staff)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    shown = client.get(url)
    page = html.unescape(shown.text)
    assert "Storage per VV (MB)" in page and _input_value(page, "storage_bytes") == "10"
    assert "JavaScript heap per VV (MB)" in page and _input_value(page, "heap_bytes") == "64"
    assert "Size of one message (KB)" in page and _input_value(page, "max_message_bytes") == "64"
    assert "10485760" not in page and "67108864" not in page

    saved = client.post(url, form_as_shown(shown) | {"storage_bytes": "25"})
    assert saved.status_code == 302, saved.content.decode()[:2000]
    customer_a.refresh_from_db()
    customer_b.refresh_from_db()
    assert customer_a.storage_bytes == 26_214_400
    assert (customer_a.heap_bytes, customer_a.max_message_bytes) == (67_108_864, 65_536)
    assert customer_b.storage_bytes == 10_485_760
    assert _input_value(client.get(url).text, "storage_bytes") == "25"


def test_a_customer_added_in_the_admin_gets_its_sizes_in_bytes(client, staff) -> None:
    client.force_login(staff)
    add = reverse("admin:accounts_customer_add")
    shown = client.get(add)
    assert _input_value(shown.text, "storage_bytes") == "10", "the default, in MB"
    form = form_as_shown(shown) | {"name": "Acme", "slug": "acme", "storage_bytes": "2.5"}
    added = client.post(add, form | {"allowed_api_calls": ["log"]})
    assert added.status_code == 302, added.content.decode()[:2000]
    acme = Customer.objects.get(slug="acme")
    assert (acme.storage_bytes, acme.heap_bytes) == (2_621_440, 67_108_864)
    assert (acme.max_message_bytes, acme.allowed_api_calls) == (65_536, ["log"])


def test_a_size_that_is_no_whole_number_of_mb_is_kept_when_the_form_is_saved_untouched(
    client, staff, customer_a
) -> None:
    Customer.objects.filter(pk=customer_a.pk).update(storage_bytes=1_000_000)  # over the API
    client.force_login(staff)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    shown = client.get(url)
    assert _input_value(shown.text, "storage_bytes") == "0.954"
    saved = client.post(url, form_as_shown(shown) | {"max_parallel_vvs": "7"})
    assert saved.status_code == 302, saved.content.decode()[:2000]
    customer_a.refresh_from_db()
    assert (customer_a.storage_bytes, customer_a.max_parallel_vvs) == (1_000_000, 7)


def test_a_size_below_the_models_least_is_refused_in_the_unit_shown(
    client, staff, customer_a
) -> None:
    client.force_login(staff)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    form = form_as_shown(client.get(url))
    refused = client.post(url, form | {"heap_bytes": "0.5", "storage_bytes": "-1"})
    assert refused.status_code == 200
    errors = refused.context["adminform"].form.errors
    assert errors["heap_bytes"] == ["At least 1 MB."]
    assert errors["storage_bytes"] == ["At least 0 MB."]
    customer_a.refresh_from_db()
    assert (customer_a.heap_bytes, customer_a.storage_bytes) == (67_108_864, 10_485_760)


def test_the_customer_form_names_every_quota_in_words_with_its_unit(
    client, staff, customer_a
) -> None:
    client.force_login(staff)
    page = html.unescape(
        client.get(reverse("admin:accounts_customer_change", args=[customer_a.pk])).text
    )
    for label in [
        "VVs running at once",
        "VVs waiting in the queue",
        "Tasks per VV",
        "Storage per VV (MB)",
        "CPU time per step (ms)",
        "JavaScript heap per VV (MB)",
        "Messages sent per VV",
        "Size of one message (KB)",
        "Sensors allowed",
        "VVM-API calls allowed",
    ]:
        assert f"{label}:</label>" in page, label
    for raw in ["Storage bytes", "Allowed api calls", "Cpu ms per step", "Max parallel vvs"]:
        assert raw not in page, raw
    listed = html.unescape(client.get(reverse("admin:accounts_customer_changelist")).text)
    assert "VVs at once" in listed and "Max parallel vvs" not in listed


def test_the_allowed_api_calls_are_boxes_to_tick_and_kept_as_a_list(
    client, staff, customer_a
) -> None:
    client.force_login(staff)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    shown = client.get(url)
    boxes = re.findall(
        r'<input type="checkbox" name="allowed_api_calls" value="([\w.]+)"', shown.text
    )
    assert sorted(boxes) == sorted(VVM_API_CALLS)

    ticked = client.post(
        url, form_as_shown(shown) | {"allowed_api_calls": ["task.execute", "sensor.get"]}
    )
    assert ticked.status_code == 302, ticked.content.decode()[:2000]
    customer_a.refresh_from_db()
    assert customer_a.allowed_api_calls == ["sensor.get", "task.execute"]
    again = client.get(url)
    assert again.context["adminform"].form["allowed_api_calls"].value() == [
        "sensor.get",
        "task.execute",
    ]
    assert len(re.findall(r'name="allowed_api_calls" value="[\w.]+"[^>]*checked', again.text)) == 2

    untouched = form_as_shown(again)
    cleared = {k: v for k, v in untouched.items() if k != "allowed_api_calls"}
    assert client.post(url, cleared).status_code == 302
    customer_a.refresh_from_db()
    assert customer_a.allowed_api_calls == [], "none ticked: every call"


@pytest.mark.parametrize("model", ["apitoken", "webhook"])
def test_the_lists_load_and_offer_no_add(client, staff, user_a, model) -> None:
    token, _ = api_token_create(user=user_a, name="laptop")
    webhook = webhook_create(
        customer=user_a.customer,
        url="http://127.0.0.1:9/h",
        events=["vv.failed"],
        allow_private=True,
    )
    client.force_login(staff)
    changelist = client.get(reverse(f"admin:accounts_{model}_changelist"))
    assert changelist.status_code == 200
    add = reverse(f"admin:accounts_{model}_add")
    assert client.get(add).status_code == 403 and f'href="{add}"' not in changelist.text
    shown = client.get(
        reverse(
            f"admin:accounts_{model}_change", args=[(token if model == "apitoken" else webhook).pk]
        )
    )
    assert shown.status_code == 200
    assert webhook.secret not in shown.text and token.digest not in shown.text


def test_deleting_in_the_admin_revokes_and_unlistens(client, staff, user_a, settings) -> None:
    settings.CPCC_TOKEN_CACHE_S = 10.0
    token, key = api_token_create(user=user_a, name="laptop")
    webhook = webhook_create(
        customer=user_a.customer,
        url="http://127.0.0.1:9/h",
        events=["vv.failed"],
        allow_private=True,
    )
    api = APIClient()
    api.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    assert api.get("/api/v1/vvs/").status_code == 200
    client.force_login(staff)
    for model, obj in (("apitoken", token), ("webhook", webhook)):
        url = reverse(f"admin:accounts_{model}_delete", args=[obj.pk])
        assert client.post(url, {"post": "yes"}).status_code == 302
    assert not ApiToken.objects.exists() and not Webhook.objects.exists()
    assert api.get("/api/v1/vvs/").status_code == 401
    assert Customer.objects.get(pk=user_a.customer_id).notify_events == []
