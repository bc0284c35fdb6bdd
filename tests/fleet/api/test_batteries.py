"""Batteries and maintenance over the staff API (issue 58): the vehicle's ``maintenance``, the
logbook's ``batteries``, GET /api/v1/batteries/, POST .../maintenance-record/ (fleet managers)
and .../battery/ (a swap: its pilots too); customers and support are refused the writes."""

from __future__ import annotations

import datetime as dt

import pytest
from django.contrib.auth.models import Group
from django.utils import timezone
from rest_framework.test import APIClient

import fleet.api.views
from accounts.roles import FLEET_MANAGER, PILOT, SUPPORT
from fleet.models import Battery, Flight, MaintenanceInterval, MaintenanceRecord, VehicleStatus
from tests.factories import UserFactory, VehicleFactory
from vvm_worker.services import battery_observe, vehicle_check_maintenance

pytestmark = pytest.mark.django_db


@pytest.fixture(autouse=True)
def recorded(monkeypatch, vvm_factory):
    vvm = vvm_factory()
    monkeypatch.setattr(fleet.api.views, "platform_vvm", lambda: vvm)
    return vvm


def client_of(username: str, group: str) -> APIClient:
    user = UserFactory(username=username, is_staff=True)
    user.groups.add(Group.objects.get(name=group))
    client = APIClient()
    client.force_authenticate(user)
    return client


@pytest.fixture
def heli(db):
    vehicle = VehicleFactory(name="Heli One")
    start = timezone.now() - dt.timedelta(hours=5)
    for i in range(9):
        began = start + dt.timedelta(minutes=20 * i)
        Flight.objects.create(
            vehicle=vehicle,
            started=began,
            started_s=0.0,
            ended=began + dt.timedelta(minutes=10),
            duration_s=600.0,
        )
    return vehicle


def test_the_vehicle_shows_what_is_due_and_the_logbook_its_battery(heli) -> None:
    MaintenanceInterval.objects.create(name="10-flight check", every_flights=10)
    battery_observe(vehicle_id=heli.pk, pct=45, now=timezone.now())
    battery_observe(vehicle_id=heli.pk, pct=95, now=timezone.now())
    manager = client_of("fm", FLEET_MANAGER)
    shown = manager.get(f"/api/v1/vehicles/{heli.pk}/").json()
    assert shown["maintenance"]["overdue"] == []
    [due] = shown["maintenance"]["due_soon"]
    assert {k: due[k] for k in ("name", "kind", "used", "limit")} == {
        "name": "10-flight check",
        "kind": "flights",
        "used": 9,
        "limit": 10,
    }
    listed = manager.get("/api/v1/vehicles/").json()["results"]
    assert listed[0]["maintenance"]["due_soon"][0]["name"] == "10-flight check"
    logbook = manager.get(f"/api/v1/vehicles/{heli.pk}/logbook/").json()
    [battery] = logbook["batteries"]
    assert (battery["name"], battery["cycles"], battery["lowest_pct"]) == (
        "Heli One battery",
        1,
        45.0,
    )


def test_the_battery_list_shows_cycles_and_what_is_due(heli) -> None:
    MaintenanceInterval.objects.create(name="Packs", retire_cycles=10)
    Battery.objects.create(name="Pack 1", vehicle=heli, cycles=9, flights=3, flight_s=5400.0)
    Battery.objects.create(name="Pack 2", cycles=12, retired=timezone.now())
    support = client_of("help", SUPPORT)
    rows = support.get("/api/v1/batteries/").json()["results"]
    by_name = {row["name"]: row for row in rows}
    assert by_name["Pack 1"]["vehicle"] == "Heli One"
    assert (by_name["Pack 1"]["flights"], by_name["Pack 1"]["flight_hours"]) == (3, 1.5)
    assert [(d["name"], d["used"], d["retire"]) for d in by_name["Pack 1"]["due"]] == [
        ("Packs: retirement", 9, True)
    ]
    assert by_name["Pack 2"]["retired"] is not None
    retired = support.get("/api/v1/batteries/?retired=true").json()["results"]
    assert [row["name"] for row in retired] == ["Pack 2"]
    assert support.get("/api/v1/batteries/?retired=maybe").status_code == 400


def test_recording_maintenance_returns_a_grounded_rv(heli, recorded) -> None:
    check = MaintenanceInterval.objects.create(name="9-flight check", every_flights=9)
    vehicle_check_maintenance(vehicle_id=heli.pk, vvm=recorded)
    heli.refresh_from_db()
    assert (heli.status, heli.status_reason) == (
        VehicleStatus.MAINTENANCE,
        "grounded: 9-flight check overdue",
    )
    manager = client_of("fm", FLEET_MANAGER)
    empty = manager.post(f"/api/v1/vehicles/{heli.pk}/maintenance-record/", {}, format="json")
    assert empty.status_code == 400
    unknown = manager.post(
        f"/api/v1/vehicles/{heli.pk}/maintenance-record/", {"interval": 999}, format="json"
    )
    assert unknown.status_code == 400 and "interval" in unknown.json()
    response = manager.post(
        f"/api/v1/vehicles/{heli.pk}/maintenance-record/",
        {"interval": check.pk, "notes": "all good"},
        format="json",
    )
    assert response.status_code == 200, response.content
    assert response.json()["status"] == "active"
    assert response.json()["maintenance"] == {"due_soon": [], "overdue": []}
    record = MaintenanceRecord.objects.get(vehicle=heli)
    assert (record.what, record.by_name, record.notes) == ("9-flight check", "fm", "all good")


def test_a_pilot_records_a_battery_swap_on_their_rv_only(heli) -> None:
    pilot = client_of("pilot-one", PILOT)
    heli.pilots.add(UserFactory._meta.model.objects.get(username="pilot-one"))
    elsewhere = VehicleFactory(name="Heli Elsewhere")
    response = pilot.post(f"/api/v1/vehicles/{heli.pk}/battery/", {"name": "Pack 3"}, format="json")
    assert response.status_code == 200, response.content
    assert Battery.objects.get(name="Pack 3").vehicle == heli
    refused = pilot.post(
        f"/api/v1/vehicles/{elsewhere.pk}/battery/", {"name": "Pack 4"}, format="json"
    )
    assert refused.status_code == 403
    assert pilot.post(
        f"/api/v1/vehicles/{heli.pk}/maintenance-record/", {"what": "props"}, format="json"
    ).status_code == 403  # fmt: skip


def test_customers_and_support_are_refused_the_writes(api_a, api_b, heli) -> None:
    support = client_of("help", SUPPORT)
    for client in (api_a, api_b, support):
        for path, body in (("maintenance-record", {"what": "props"}), ("battery", {"name": "P"})):
            response = client.post(f"/api/v1/vehicles/{heli.pk}/{path}/", body, format="json")
            assert response.status_code == 403, (path, response.content)
    for client in (api_a, api_b):
        assert client.get("/api/v1/batteries/").status_code == 403
    assert not MaintenanceRecord.objects.exists()
    assert not Battery.objects.exists()
