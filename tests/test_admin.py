"""Every admin page of the platform's models loads for staff and is closed to customers."""

from __future__ import annotations

import pytest
from django.urls import reverse

from tests.factories import GroundStationFactory, VehicleFactory
from vvm_worker.services import vv_submit

MODELS = [
    ("accounts", "customer"),
    ("accounts", "user"),
    ("fleet", "sensortype"),
    ("fleet", "groundstation"),
    ("fleet", "vehicle"),
    ("missions", "virtualvehicle"),
    ("missions", "task"),
    ("missions", "storagedocument"),
    ("missions", "logentry"),
    ("missions", "migration"),
]


@pytest.fixture
def populated(customer_a, user_a, vvm_factory):
    GroundStationFactory(name="GS Base")
    VehicleFactory(name="Heli One")
    return vv_submit(customer=customer_a, name="VV 1", program="var a = 1;", vvm=vvm_factory())


def test_admin_index_loads(client, staff) -> None:
    client.force_login(staff)
    response = client.get(reverse("admin:index"))
    assert response.status_code == 200
    for app in ("Customers and users", "Fleet", "Missions"):
        assert app in response.text


@pytest.mark.parametrize(("app", "model"), MODELS)
def test_admin_changelist_and_add_pages_load(client, staff, populated, app, model) -> None:
    client.force_login(staff)
    assert client.get(reverse(f"admin:{app}_{model}_changelist")).status_code == 200
    assert client.get(reverse(f"admin:{app}_{model}_add")).status_code == 200


@pytest.mark.parametrize(
    ("app", "model", "lookup"),
    [
        ("missions", "virtualvehicle", lambda vv: vv.pk),
        ("accounts", "customer", lambda vv: vv.customer_id),
        ("fleet", "vehicle", lambda vv: VehicleFactory(name="Heli One").pk),
    ],
)
def test_admin_change_pages_load(client, staff, populated, app, model, lookup) -> None:
    client.force_login(staff)
    url = reverse(f"admin:{app}_{model}_change", args=[lookup(populated)])
    assert client.get(url).status_code == 200


def test_customers_cannot_open_the_admin(client, user_a) -> None:
    client.force_login(user_a)
    response = client.get(reverse("admin:missions_virtualvehicle_changelist"))
    assert response.status_code == 302
    assert "/admin/login/" in response["Location"]


def test_admin_actions_take_an_rv_out_of_service_and_back(
    client, staff, populated, monkeypatch
) -> None:
    from fleet.models import Vehicle, VehicleStatus

    calls = []
    monkeypatch.setattr(
        "vvm_worker.services.vehicle_set_status",
        lambda *, vehicle, status, vvm: calls.append((vehicle.name, status)),
    )
    client.force_login(staff)
    heli = Vehicle.objects.get(name="Heli One")
    url = reverse("admin:fleet_vehicle_changelist")
    for action, status in [
        ("put_into_maintenance", VehicleStatus.MAINTENANCE),
        ("return_to_service", VehicleStatus.ACTIVE),
        ("remove_from_fleet", VehicleStatus.REMOVED),
    ]:
        response = client.post(url, {"action": action, "_selected_action": [heli.pk]}, follow=True)
        assert response.status_code == 200
        assert calls[-1] == ("Heli One", status)


def test_a_vehicle_added_in_the_admin_takes_work(client, staff, db, monkeypatch) -> None:
    from fleet.models import SensorType

    registered = []
    monkeypatch.setattr(
        "vvm_worker.services.vehicle_register",
        lambda *, vehicle, vvm: registered.append(vehicle.name),
    )
    client.force_login(staff)
    gps = SensorType.objects.get(name="GPS")
    response = client.post(
        reverse("admin:fleet_vehicle_add"),
        {
            "name": "Heli Three",
            "driver": "sim",
            "driver_url": "",
            "depot_lat": 48.11,
            "depot_lng": 12.86,
            "depot_alt": 0,
            "area": "[[48.109, 12.859], [48.109, 12.868], [48.114, 12.868], [48.109, 12.859]]",
            "min_altitude_m": 0,
            "max_altitude_m": 100,
            "max_speed_mps": 10,
            "climb_rate_mps": 3,
            "battery_s": "",
            "sensors": [gps.pk],
        },
    )
    assert response.status_code == 302, response.content.decode()[:2000]
    assert registered == ["Heli Three"]
