"""The audit log: who changed what in the fleet, the customers, their quotas and the SDC."""

from __future__ import annotations

import pytest
from auditlog.models import LogEntry
from django.urls import reverse

from accounts.models import Customer
from fleet.models import Vehicle
from tests.api_fixtures import token_client
from tests.factories import VehicleFactory

pytestmark = pytest.mark.django_db


def entries(obj) -> list[LogEntry]:
    return list(LogEntry.objects.get_for_object(obj).order_by("timestamp", "pk"))


def test_a_change_over_the_api_is_logged_with_the_token_user(staff) -> None:
    vehicle = VehicleFactory(name="Heli Nine", max_speed_mps=10.0)
    api = token_client(staff)
    response = api.patch(f"/api/v1/vehicles/{vehicle.pk}/", {"max_speed_mps": 12.5}, format="json")
    assert response.status_code == 200, response.content
    change = entries(vehicle)[-1]
    assert change.action == LogEntry.Action.UPDATE
    assert change.actor == staff
    assert change.changes_dict["max_speed_mps"] == ["10.0", "12.5"]


def test_quota_changes_over_the_api_are_logged(staff, customer_a) -> None:
    api = token_client(staff)
    response = api.patch(
        f"/api/v1/customers/{customer_a.pk}/", {"max_parallel_vvs": 7}, format="json"
    )
    assert response.status_code == 200, response.content
    change = entries(Customer.objects.get(pk=customer_a.pk))[-1]
    assert change.actor == staff
    assert change.changes_dict["max_parallel_vvs"][1] == "7"


def test_an_sdc_entry_added_in_the_admin_is_logged_with_the_staff_user(client, staff) -> None:
    client.force_login(staff)
    response = client.post(
        reverse("admin:fleet_sensortype_add"),
        {"name": "Humidity", "description": "Relative humidity", "kind": "scalar", "unit": "%",
         "params": "{}"},
    )  # fmt: skip
    assert response.status_code == 302, response.content.decode()[:2000]
    added = LogEntry.objects.filter(object_repr__contains="Humidity").get()
    assert added.action == LogEntry.Action.CREATE
    assert added.actor == staff


def test_the_vehicles_own_flying_is_not_logged_as_a_change() -> None:
    vehicle = VehicleFactory(name="Heli Ten")
    before = len(entries(vehicle))
    Vehicle.objects.filter(pk=vehicle.pk).update(lat=48.11, lng=12.86, phase="cruise")
    vehicle.refresh_from_db()
    vehicle.distance_m = 120.0
    vehicle.save()
    assert len(entries(vehicle)) == before


def test_staff_read_the_log_in_the_admin_and_customers_do_not(client, staff, user_a) -> None:
    VehicleFactory(name="Heli Eleven")
    client.force_login(staff)
    page = client.get("/admin/auditlog/logentry/")
    assert page.status_code == 200
    assert b"Heli Eleven" in page.content
    client.force_login(user_a)
    assert client.get("/admin/auditlog/logentry/").status_code == 302  # to the admin login
