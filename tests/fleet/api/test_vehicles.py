"""/api/v1/vehicles/ (staff only): add, configure, pause, return and remove RVs."""

from __future__ import annotations

import pytest

import fleet.api.views
import vvm_worker.services.fleet
from fleet.models import Vehicle, VehicleStatus
from missions.models import VVStatus
from tests.factories import AREA_ONE, AREA_TWO, VehicleFactory
from vvm_worker.services import vehicle_record_health, vehicle_set_status, vv_submit

NEW = {
    "name": "Heli Three",
    "depot": [48.1135, 12.86],
    "area": AREA_TWO,
    "max_altitude_m": 100,
    "max_speed_mps": 8,
    "sensors": ["CO2", "GPS"],
}


@pytest.fixture
def register_calls(monkeypatch) -> list[str]:
    """The calls of vehicle_register, recorded instead of run: for the tests that are about
    whether the API asks for it at all (the real thing: test_staff_add_a_vehicle_that_gets_work_at_once)."""
    seen: list[str] = []

    def record(*, vehicle, vvm) -> None:
        seen.append(vehicle.name)

    monkeypatch.setattr(vvm_worker.services.fleet, "vehicle_register", record)
    return seen


def test_customers_are_refused_with_a_clear_message(api_a, heli_one) -> None:
    for method, url in [
        ("get", "/api/v1/vehicles/"),
        ("post", "/api/v1/vehicles/"),
        ("get", f"/api/v1/vehicles/{heli_one.pk}/"),
        ("patch", f"/api/v1/vehicles/{heli_one.pk}/"),
        ("post", f"/api/v1/vehicles/{heli_one.pk}/maintenance/"),
        ("delete", f"/api/v1/vehicles/{heli_one.pk}/"),
    ]:
        response = getattr(api_a, method)(url, {}, format="json")
        assert response.status_code == 403, url
        assert "Only platform staff" in response.json()["detail"]
    heli_one.refresh_from_db()
    assert heli_one.status == VehicleStatus.ACTIVE


def test_staff_add_a_vehicle_that_gets_work_at_once(
    api_staff, platform, ground_station, customer_a, monkeypatch
) -> None:
    monkeypatch.setattr(fleet.api.views, "platform_vvm", lambda: platform.vvm)
    program = """
    var co2 = VV.sensor.get('CO2');
    var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1135, 12.8655, 50),
                             tolerance: 2, sensors: [co2]});
    VV.storage.store('co2', d[0]);
    """
    # A slow RV over the same area has the VV's task when the new one comes.
    slow = VehicleFactory(name="Heli Slow", area=AREA_TWO, max_speed_mps=0.5)
    platform.add_vehicle_loop(slow)
    vv = vv_submit(customer=customer_a, name="VV", program=program, vvm=platform.vvm)
    platform.drain(until=lambda: vv.tasks.filter(vehicle=slow).exists())
    response = api_staff.post("/api/v1/vehicles/", NEW, format="json")
    assert response.status_code == 201, response.content
    body = response.json()
    assert body["name"] == "Heli Three" and body["status"] == "active"
    assert body["depot"] == [48.1135, 12.86, 0.0] and body["area"] == AREA_TWO
    assert body["sensors"] == ["CO2", "GPS"] and body["min_altitude_m"] == 0.0
    assert body["position"] is None
    assert body["vvs_aboard"] == 1, "the VV moved to the new, faster RV at once"
    vehicle = Vehicle.objects.get(name="Heli Three")
    platform.add_vehicle_loop(vehicle)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert vv.tasks.get().vehicle == vehicle and vv.storage.filter(key="co2").exists()
    assert ("Heli Slow", "Heli Three") in vv.migrations.values_list("from_name", "to_name")
    assert sorted(vehicle.sensors.values_list("name", flat=True)) == ["CO2", "GPS"]
    listed = api_staff.get("/api/v1/vehicles/").json()
    assert [v["name"] for v in listed["results"]] == ["Heli Slow", "Heli Three"]
    assert api_staff.get(f"/api/v1/vehicles/{vehicle.pk}/").json()["name"] == "Heli Three"


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"area": AREA_TWO[:-1]}, "area", "must be closed"),
        ({"area": [[48.1, 12.8], [48.2, 12.9], [48.1, 12.8]]}, "area", "at least 3 distinct"),
        (
            {"area": [[48.0, 12.0], [48.1, 12.1], [48.0, 12.1], [48.1, 12.0], [48.0, 12.0]]},
            "area",
            "not a valid polygon",
        ),
        ({"area": [[48.1, 12.8], [91, 12.9], [48.2, 12.9], [48.1, 12.8]]}, "area", "latitude 91"),
        ({"area": "a box"}, "area", "Expected a list of items"),
        ({"sensors": ["CO2", "Sonar", "Lidar"]}, "sensors", "'Lidar', 'Sonar'"),
        ({"min_altitude_m": 150}, "max_altitude_m", "must not be below min_altitude_m"),
        ({"depot": [48.1, 200]}, "depot", "longitude 200"),
        ({"max_speed_mps": 0}, "max_speed_mps", "greater than or equal to 0.1"),
        ({"driver": "rocket"}, "driver", '"rocket" is not a valid choice'),
        (
            {"sensor_sources": {"CO2": {"source": "telemetry"}}},
            "sensor_sources",
            "sensor 'CO2': telemetry needs a vehicle that speaks MAVLink",
        ),
        ({"sensor_sources": {"CO2": "field"}}, "sensor_sources", "Expected a dictionary"),
    ],
)
def test_bad_configurations_are_refused_naming_the_field(
    api_staff, register_calls, change, field, words
) -> None:
    response = api_staff.post("/api/v1/vehicles/", {**NEW, **change}, format="json")
    assert response.status_code == 400
    errors = response.json()
    detail = errors.pop("detail")
    assert list(errors) == [field], errors
    assert words in str(errors[field])
    assert detail.startswith(f"{field}: ") or detail.startswith(f"{field}.")
    assert not Vehicle.objects.exists() and register_calls == []


def test_a_name_in_use_and_missing_fields_are_named(api_staff, heli_one, register_calls) -> None:
    taken = api_staff.post("/api/v1/vehicles/", {**NEW, "name": "Heli One"}, format="json")
    assert taken.status_code == 409 and "already exists" in str(taken.json()["name"])
    missing = api_staff.post("/api/v1/vehicles/", {"name": "X"}, format="json")
    assert missing.status_code == 400
    assert {"depot", "area", "max_altitude_m", "max_speed_mps"} <= set(missing.json())


def test_staff_change_a_configuration(api_staff, heli_one, register_calls) -> None:
    url = f"/api/v1/vehicles/{heli_one.pk}/"
    response = api_staff.patch(
        url, {"max_speed_mps": 12.5, "depot": [48.1, 12.86, 3]}, format="json"
    )
    assert response.status_code == 200, response.content
    assert response.json()["max_speed_mps"] == 12.5 and response.json()["depot"] == [48.1, 12.86, 3]
    assert register_calls == [], "its reach did not change"
    response = api_staff.patch(url, {"sensors": ["GPS"], "area": AREA_TWO}, format="json")
    assert response.json()["sensors"] == ["GPS"] and response.json()["area"] == AREA_TWO
    assert register_calls == ["Heli One"]
    bad = api_staff.patch(url, {"area": AREA_TWO[:3]}, format="json")
    assert bad.status_code == 400 and "closed" in str(bad.json()["area"])
    assert api_staff.put(url, NEW, format="json").status_code == 405


def test_staff_wire_a_vehicles_sensors(api_staff, heli_one, register_calls) -> None:
    """Issue 24: where each sensor's readings come from, shown back as configured."""
    url = f"/api/v1/vehicles/{heli_one.pk}/"
    assert api_staff.get(url).json()["sensor_sources"] == {}
    sources = {
        "CO2": {"source": "named_value", "name": "CO2"},
        "Thermometer": {"source": "telemetry", "timeout_s": 5},
    }
    response = api_staff.patch(
        url,
        {"driver": "mavlink", "driver_url": "udpin:0.0.0.0:14550", "sensor_sources": sources},
        format="json",
    )
    assert response.status_code == 200, response.content
    assert response.json()["sensor_sources"] == sources
    unknown = api_staff.patch(
        url, {"sensor_sources": {"CO2": {"source": "plugin", "plugin": "geiger"}}}, format="json"
    )
    assert unknown.status_code == 400
    assert "no sensor plug-in named 'geiger' (plug-ins: mhz19)" in str(unknown.json())
    assert api_staff.get(url).json()["sensor_sources"] == sources


def test_a_vehicle_that_loses_a_sensor_hands_its_vv_to_one_that_has_it(
    platform, fleet_one, customer_a, api_staff, monkeypatch
) -> None:
    # Heli Two could serve the task too, but slowly: the VV goes to Heli One first.
    two = VehicleFactory(name="Heli Two", area=[list(p) for p in AREA_ONE], max_speed_mps=1.0)
    platform.add_vehicle_loop(two)
    monkeypatch.setattr(fleet.api.views, "platform_vvm", lambda: platform.vvm)
    program = """
    var co2 = VV.sensor.get('CO2');
    var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1101, 12.8622, 50),
                             tolerance: 2, sensors: [co2]});
    VV.storage.store('co2', d[0]);
    """
    vv = vv_submit(customer=customer_a, name="VV", program=program, vvm=platform.vvm)
    platform.drain(until=lambda: vv.tasks.filter(vehicle=fleet_one).exists())
    response = api_staff.patch(
        f"/api/v1/vehicles/{fleet_one.pk}/", {"sensors": ["GPS", "Thermometer"]}, format="json"
    )
    assert response.status_code == 200
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert vv.tasks.get().vehicle == two
    moves = [(m.from_name, m.to_name) for m in vv.migrations.all()]
    assert ("Heli One", "Heli Two") in moves


def test_commands_pause_return_and_remove_a_vehicle(api_staff, heli_one) -> None:
    url = f"/api/v1/vehicles/{heli_one.pk}/"
    for command, status in [
        ("maintenance", "maintenance"),
        ("return", "active"),
        ("remove", "removed"),
    ]:
        response = api_staff.post(url + f"{command}/")
        assert response.status_code == 200, response.content
        assert response.json()["status"] == status
        heli_one.refresh_from_db()
        assert heli_one.status == status
    removed = api_staff.get("/api/v1/vehicles/?status=removed").json()["results"]
    assert [v["name"] for v in removed] == ["Heli One"]
    assert api_staff.get("/api/v1/vehicles/?status=active").json()["results"] == []


def test_delete_removes_but_keeps_the_vehicle(api_staff, heli_one) -> None:
    url = f"/api/v1/vehicles/{heli_one.pk}/"
    response = api_staff.delete(url)
    assert response.status_code == 200 and response.json()["status"] == "removed"
    assert Vehicle.objects.get(pk=heli_one.pk).status == VehicleStatus.REMOVED
    # Gone for the API (a second DELETE too), its record kept for its history.
    for method, path in [("get", url), ("patch", url), ("delete", url), ("post", url + "return/")]:
        gone = getattr(api_staff, method)(path, {}, format="json")
        assert gone.status_code == 404, (method, path)
        assert "was removed from the fleet" in gone.json()["detail"]
    removed = api_staff.get("/api/v1/vehicles/?status=removed").json()["results"]
    assert [v["id"] for v in removed] == [heli_one.pk]


def test_an_unknown_vehicle_is_a_404_that_says_which(api_staff, db) -> None:
    response = api_staff.post("/api/v1/vehicles/999/maintenance/")
    assert response.status_code == 404
    assert response.json() == {"detail": "No vehicle with id '999'."}


def test_a_vehicle_shows_why_and_when_its_status_changed_and_its_health(
    api_staff, heli_one
) -> None:
    url = f"/api/v1/vehicles/{heli_one.pk}/"
    shown = api_staff.post(url + "maintenance/").json()
    assert shown["status"] == "maintenance"
    assert shown["status_reason"].startswith("set by ") and shown["status_reason"].endswith(
        " over the API"
    )
    assert shown["status_changed"] is not None
    assert (shown["health"], shown["health_changed"]) == ({}, None)  # no worker has looked
    health = {"link": "down", "armed": True, "mode": "GUIDED", "battery_pct": 54}
    vehicle_record_health(vehicle_id=heli_one.pk, health=health)
    shown = api_staff.get(url).json()
    assert shown["health"] == health and shown["health_changed"] is not None
    assert shown["status"] == "maintenance"  # health does not touch the status


@pytest.mark.django_db
def test_the_platform_never_overrides_a_persons_decision(vvm_factory, heli_one) -> None:
    vvm = vvm_factory()
    vehicle_set_status(vehicle=heli_one, status=VehicleStatus.MAINTENANCE, vvm=vvm, reason="check")
    # The link returns, a charge ends: each only from the status the platform set itself.
    for status, expected in [
        (VehicleStatus.ACTIVE, VehicleStatus.OFFLINE),
        (VehicleStatus.ACTIVE, VehicleStatus.CHARGING),
        (VehicleStatus.OFFLINE, VehicleStatus.ACTIVE),
    ]:
        changed = vehicle_set_status(
            vehicle=heli_one, status=status, vvm=vvm, reason="platform", expected=expected
        )
        assert not changed
    heli_one.refresh_from_db()
    assert (heli_one.status, heli_one.status_reason) == (VehicleStatus.MAINTENANCE, "check")
