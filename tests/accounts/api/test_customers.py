"""/api/v1/customers/ (staff only): customers and their quotas."""

from __future__ import annotations

import re
from pathlib import Path

import accounts.api.views
from accounts.models import (
    DEFAULT_MAX_MESSAGE_BYTES,
    DEFAULT_MAX_MESSAGES_PER_VV,
    DEFAULT_MAX_PARALLEL_VVS,
    DEFAULT_MAX_QUEUED_VVS,
    Customer,
)
from vvm_worker.runtime import VVM_API_CALLS
from vvm_worker.services import customer_limits, vv_submit

PRELUDE = Path(__file__).resolve().parents[3] / "vvm_worker" / "runtime" / "prelude.js"


def test_customers_are_refused_with_a_clear_message(api_a, customer_a) -> None:
    for response in [
        api_a.get("/api/v1/customers/"),
        api_a.get(f"/api/v1/customers/{customer_a.pk}/"),
        api_a.post("/api/v1/customers/", {"name": "Mine"}, format="json"),
        api_a.patch(f"/api/v1/customers/{customer_a.pk}/", {"max_parallel_vvs": 99}, format="json"),
        api_a.delete(f"/api/v1/customers/{customer_a.pk}/"),
    ]:
        assert response.status_code == 403
        assert "Only platform staff" in response.json()["detail"]
    customer_a.refresh_from_db()
    assert customer_a.max_parallel_vvs == DEFAULT_MAX_PARALLEL_VVS


def test_staff_create_a_customer_with_quotas(api_staff, db) -> None:
    response = api_staff.post(
        "/api/v1/customers/",
        {
            "name": "Customer C",
            "max_parallel_vvs": 2,
            "max_tasks_per_vv": 50,
            "storage_bytes": 1000,
            "cpu_ms_per_step": 500,
            "heap_bytes": 16 * 1024 * 1024,
            "privileged": True,
            "allowed_sensors": ["CO2", "Battery"],
            "allowed_api_calls": ["task.execute", "storage.store", "log"],
        },
        format="json",
    )
    assert response.status_code == 201, response.content
    body = response.json()
    assert body["slug"] == "customer-c" and body["max_parallel_vvs"] == 2
    assert body["allowed_sensors"] == ["Battery", "CO2"] and body["privileged"] is True
    assert body["allowed_api_calls"] == ["task.execute", "storage.store", "log"]
    assert body["users"] == [] and body["vvs_active"] == 0
    customer = Customer.objects.get(slug="customer-c")
    assert customer.cpu_ms_per_step == 500 and customer.heap_bytes == 16 * 1024 * 1024
    defaults = api_staff.post("/api/v1/customers/", {"name": "Plain"}, format="json").json()
    assert defaults["max_parallel_vvs"] == DEFAULT_MAX_PARALLEL_VVS
    assert defaults["allowed_sensors"] == [] and defaults["allowed_api_calls"] == []


def test_bad_quotas_are_refused_naming_the_field(api_staff, customer_a) -> None:
    cases = [
        ({"name": "X", "allowed_sensors": ["CO2", "Sonar"]}, "allowed_sensors", "'Sonar'"),
        (
            {"name": "X", "allowed_api_calls": ["task.teleport"]},
            "allowed_api_calls",
            "task.teleport",
        ),
        ({"name": "X", "max_parallel_vvs": 0}, "max_parallel_vvs", "greater than or equal to 1"),
        ({"name": "X", "heap_bytes": 10}, "heap_bytes", "greater than or equal to 1048576"),
        ({"name": "Customer A"}, "name", "already exists"),
        ({}, "name", "required"),
        ({"name": "X", "slug": 0}, "slug", "Expected a string"),
    ]
    for data, field, words in cases:
        response = api_staff.post("/api/v1/customers/", data, format="json")
        # A name in use is a conflict with what is stored (409), the rest malformed (400).
        assert response.status_code == (409 if words == "already exists" else 400), data
        assert field in response.json(), response.json()
        assert words in str(response.json()[field])
    assert Customer.objects.count() == 1


def test_staff_change_quotas_and_more_parallel_vvs_admit_queued_ones(
    api_staff, customer_a, user_a, vvm_factory, monkeypatch
) -> None:
    vvm = vvm_factory()
    monkeypatch.setattr(accounts.api.views, "platform_vvm", lambda: vvm)
    url = f"/api/v1/customers/{customer_a.pk}/"
    response = api_staff.patch(
        url, {"storage_bytes": 2048, "allowed_sensors": ["GPS"]}, format="json"
    )
    assert response.status_code == 200, response.content
    assert response.json()["storage_bytes"] == 2048 and response.json()["allowed_sensors"] == [
        "GPS"
    ]
    assert response.json()["users"] == ["customer-a"] and vvm.dispatcher.slots == []
    more = api_staff.patch(url, {"max_parallel_vvs": 9}, format="json")
    assert more.json()["max_parallel_vvs"] == 9
    assert vvm.dispatcher.slots == [customer_a.pk]
    kept = api_staff.patch(url, {"privileged": True}, format="json").json()
    assert kept["allowed_sensors"] == ["GPS"] and kept["storage_bytes"] == 2048


def test_a_customer_with_vvs_running_is_not_deleted(
    api_staff, customer_a, customer_b, ground_station, vvm_factory
) -> None:
    vv_submit(customer=customer_a, name="VV", program="VV.log(1);", vvm=vvm_factory())
    busy = api_staff.delete(f"/api/v1/customers/{customer_a.pk}/")
    assert busy.status_code == 409 and "1 VV(s) that have not ended" in busy.json()["detail"]
    assert api_staff.delete(f"/api/v1/customers/{customer_b.pk}/").status_code == 204
    assert list(Customer.objects.values_list("name", flat=True)) == ["Customer A"]
    assert api_staff.get("/api/v1/customers/999/").json() == {
        "detail": "No customer with id '999'."
    }


def test_the_known_api_calls_are_those_the_runtime_checks() -> None:
    checked = set(re.findall(r"allowed\('([\w.]+)'\)", PRELUDE.read_text()))
    assert checked == set(VVM_API_CALLS)


def test_staff_see_and_set_the_queued_vv_quota_customers_cannot(
    api_staff, api_a, customer_a, customer_b
) -> None:
    url = f"/api/v1/customers/{customer_a.pk}/"
    assert api_staff.get(url).json()["max_queued_vvs"] == DEFAULT_MAX_QUEUED_VVS
    changed = api_staff.patch(url, {"max_queued_vvs": 7}, format="json")
    assert changed.status_code == 200 and changed.json()["max_queued_vvs"] == 7
    refused = api_staff.patch(url, {"max_queued_vvs": 0}, format="json")
    assert refused.status_code == 400 and "max_queued_vvs" in refused.json()
    created = api_staff.post(
        "/api/v1/customers/", {"name": "C", "max_queued_vvs": 3}, format="json"
    )
    assert created.status_code == 201 and created.json()["max_queued_vvs"] == 3
    assert api_a.patch(url, {"max_queued_vvs": 10_000}, format="json").status_code == 403
    customer_a.refresh_from_db()
    customer_b.refresh_from_db()
    assert (customer_a.max_queued_vvs, customer_b.max_queued_vvs) == (7, DEFAULT_MAX_QUEUED_VVS)


def test_staff_set_the_message_quotas_and_the_runtime_enforces_them(
    api_staff, api_a, customer_a
) -> None:
    url = f"/api/v1/customers/{customer_a.pk}/"
    shown = api_staff.get(url).json()
    assert (shown["max_messages_per_vv"], shown["max_message_bytes"]) == (
        DEFAULT_MAX_MESSAGES_PER_VV,
        DEFAULT_MAX_MESSAGE_BYTES,
    )
    changed = api_staff.patch(
        url, {"max_messages_per_vv": 0, "max_message_bytes": 300}, format="json"
    )
    assert changed.status_code == 200, changed.content
    assert (changed.json()["max_messages_per_vv"], changed.json()["max_message_bytes"]) == (0, 300)
    refused = api_staff.patch(url, {"max_message_bytes": 1}, format="json")
    assert refused.status_code == 400 and "max_message_bytes" in refused.json()
    assert api_staff.patch(url, {"max_messages_per_vv": -1}, format="json").status_code == 400
    assert api_a.patch(url, {"max_message_bytes": 10**6}, format="json").status_code == 403
    customer_a.refresh_from_db()
    limits = customer_limits(customer=customer_a)
    assert (limits.max_messages, limits.message_bytes) == (0, 300)
