"""Configuring vehicle kinds: the vehicle API and the admin take a vehicle's kind, dive and
turn rates, refuse what its kind cannot do (naming the field) and a sensor its kind cannot
carry (naming the sensor); the SDC says which kinds carry an entry."""

from __future__ import annotations

import json
from typing import Any

import pytest
from django.urls import reverse

import vvm_worker.services.fleet
from fleet.models import SensorType, Vehicle
from tests.api_fixtures import token_client
from tests.factories import AREA_TWO, VehicleFactory

SUB = {
    "name": "Sub One",
    "kind": "underwater",
    "depot": [48.1135, 12.86],
    "area": AREA_TWO,
    "min_altitude_m": -40,
    "max_altitude_m": 0,
    "max_speed_mps": 2,
    "dive_rate_mps": 0.5,
    "sensors": ["Thermometer"],
}
ROVER = {**SUB, "name": "Rover One", "kind": "ground", "min_altitude_m": 0, "dive_rate_mps": None}


@pytest.fixture(autouse=True)
def no_register(monkeypatch) -> None:
    """A new or changed vehicle is not handed work here (the fleet's tests show it is)."""
    monkeypatch.setattr(vvm_worker.services.fleet, "vehicle_register", lambda **kw: None)


@pytest.fixture
def api_staff(staff) -> Any:
    return token_client(staff)


@pytest.fixture
def api_a(user_a) -> Any:
    return token_client(user_a)


@pytest.fixture
def sonar(db) -> SensorType:
    return SensorType.objects.create(
        name="Sonar", kind="scalar", unit="m", kinds=["underwater", "surface"]
    )


def refusal(response: Any, field: str) -> str:
    assert response.status_code == 400, response.content
    errors = response.json()
    errors.pop("detail")
    assert list(errors) == [field], errors
    return str(errors[field])


# --- the vehicle API ---------------------------------------------------------------------------


def test_staff_add_an_underwater_vehicle_and_read_its_kind_back(api_staff, sonar) -> None:
    response = api_staff.post("/api/v1/vehicles/", {**SUB, "sensors": ["Sonar"]}, format="json")
    assert response.status_code == 201, response.content
    shown = response.json()
    assert (shown["kind"], shown["min_altitude_m"], shown["dive_rate_mps"]) == (
        "underwater",
        -40.0,
        0.5,
    )
    assert shown["turn_rate_dps"] is None
    again = api_staff.get(f"/api/v1/vehicles/{shown['id']}/").json()
    assert again["kind"] == "underwater" and again["sensors"] == ["Sonar"]


def test_staff_turn_an_aerial_vehicle_into_a_rover_with_its_turn_rate(api_staff, db) -> None:
    heli = VehicleFactory(name="Heli One", sensors=["Thermometer"])
    url = f"/api/v1/vehicles/{heli.pk}/"
    assert api_staff.get(url).json()["kind"] == "aerial"
    response = api_staff.patch(
        url, {"kind": "ground", "max_altitude_m": 0, "turn_rate_dps": 45}, format="json"
    )
    assert response.status_code == 200, response.content
    heli.refresh_from_db()
    assert (heli.kind, heli.max_altitude_m, heli.turn_rate_dps) == ("ground", 0.0, 45.0)


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"kind": "hovercraft"}, "kind", '"hovercraft" is not a valid choice'),
        ({"max_altitude_m": 30}, "max_altitude_m", "a ground vehicle goes no higher than 0 m"),
        ({"max_speed_mps": 35}, "max_speed_mps", "a ground vehicle moves at 30 m/s at most"),
        ({"min_altitude_m": -5}, "min_altitude_m", "a ground vehicle goes no lower than 0 m"),
        ({"turn_rate_dps": 0}, "turn_rate_dps", "greater than or equal to 1"),
        ({"kind": "underwater", "min_altitude_m": -500}, "min_altitude_m", "no lower than -300"),
        ({"sensors": ["Thermometer", "Sonar"]}, "sensors", "a ground vehicle cannot carry 'Sonar'"),
    ],
)
def test_what_its_kind_cannot_do_is_refused_naming_the_field(
    api_staff, sonar, change: dict[str, Any], field: str, words: str
) -> None:
    response = api_staff.post("/api/v1/vehicles/", {**ROVER, **change}, format="json")
    assert words in refusal(response, field)
    assert not Vehicle.objects.exists()


def test_a_new_kind_that_cannot_carry_the_sensors_aboard_is_refused(api_staff, sonar) -> None:
    created = api_staff.post("/api/v1/vehicles/", {**SUB, "sensors": ["Sonar"]}, format="json")
    url = f"/api/v1/vehicles/{created.json()['id']}/"
    response = api_staff.patch(
        url,
        {"kind": "aerial", "min_altitude_m": 0, "max_altitude_m": 50, "dive_rate_mps": None},
        format="json",
    )
    assert "an aerial vehicle cannot carry 'Sonar' (carried by underwater, surface vehicles " in (
        refusal(response, "kind")
    )
    assert Vehicle.objects.get().kind == "underwater"


def test_staff_see_which_kinds_carry_an_sdc_entry_and_customers_do_not(
    api_staff, api_a, sonar
) -> None:
    entries = {e["name"]: e for e in api_staff.get("/api/v1/sensors/").json()["results"]}
    assert entries["Sonar"]["kinds"] == ["underwater", "surface"]
    assert entries["CO2"]["kinds"] == []
    seen = {e["name"]: e for e in api_a.get("/api/v1/sensors/").json()["results"]}
    assert "kinds" not in seen["Sonar"]


# --- the admin ---------------------------------------------------------------------------------


def vehicle_form(**fields: Any) -> dict[str, Any]:
    data = {
        "name": "Rover One",
        "kind": "ground",
        "driver": "sim",
        "driver_url": "",
        "depot_lat": 48.1135,
        "depot_lng": 12.86,
        "depot_alt": 0,
        "area": json.dumps(AREA_TWO),
        "min_altitude_m": 0,
        "max_altitude_m": 0,
        "max_speed_mps": 5,
        "climb_rate_mps": 3,
        "dive_rate_mps": "",
        "turn_rate_dps": 60,
        "battery_s": "",
        "sensors": [SensorType.objects.get(name="Thermometer").pk],
    }
    return data | fields


def test_staff_add_a_rover_in_the_admin_and_filter_the_fleet_by_kind(client, staff) -> None:
    VehicleFactory(name="Heli One")
    client.force_login(staff)
    response = client.post(reverse("admin:fleet_vehicle_add"), vehicle_form())
    assert response.status_code == 302, response.content.decode()[:2000]
    rover = Vehicle.objects.get(name="Rover One")
    assert (rover.kind, rover.turn_rate_dps, rover.dive_rate_mps) == ("ground", 60.0, None)
    listed = client.get(reverse("admin:fleet_vehicle_changelist"), {"kind__exact": "ground"})
    assert "Rover One" in listed.text and "Heli One" not in listed.text
    assert "Ground (rover)" in listed.text  # the kind column


def test_the_admin_refuses_a_rover_that_climbs_or_carries_a_sonar(client, staff, sonar) -> None:
    client.force_login(staff)
    url = reverse("admin:fleet_vehicle_add")
    climbing = client.post(url, vehicle_form(max_altitude_m=30))
    assert climbing.status_code == 200
    assert "a ground vehicle goes no higher than 0 m" in climbing.text
    sonar_aboard = client.post(url, vehicle_form(sensors=[sonar.pk]))
    assert sonar_aboard.status_code == 200
    assert "a ground vehicle cannot carry &#x27;Sonar&#x27;" in sonar_aboard.text
    assert not Vehicle.objects.filter(name="Rover One").exists()


def sensor_form(**fields: Any) -> dict[str, Any]:
    data = {"name": "Sonar", "kind": "scalar", "unit": "m", "params": "{}", "description": ""}
    return data | fields


def test_the_sdc_entry_admin_ticks_the_kinds_that_carry_it(client, staff, db) -> None:
    client.force_login(staff)
    page = client.get(reverse("admin:fleet_sensortype_add")).text
    assert 'type="checkbox" name="kinds" value="underwater"' in page
    response = client.post(
        reverse("admin:fleet_sensortype_add"), sensor_form(kinds=["surface", "underwater"])
    )
    assert response.status_code == 302, response.content.decode()[:2000]
    assert SensorType.objects.get(name="Sonar").kinds == ["surface", "underwater"]


def test_the_sdc_entry_admin_keeps_the_kind_of_an_rv_that_carries_it(client, staff, sonar) -> None:
    sub = VehicleFactory(
        name="Sub One", kind="underwater", min_altitude_m=-40, max_altitude_m=0, sensors=["Sonar"]
    )
    client.force_login(staff)
    url = reverse("admin:fleet_sensortype_change", args=[sonar.pk])
    response = client.post(url, sensor_form(kinds=["surface"]))
    assert response.status_code == 200
    assert "carried by Sub One (underwater): tick their kind too" in response.text
    assert client.post(url, sensor_form(kinds=[])).status_code == 302  # every kind
    assert SensorType.objects.get(pk=sonar.pk).kinds == []
    assert sub.sensors.get().name == "Sonar"
