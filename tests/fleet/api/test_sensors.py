"""GET /api/v1/sensors/: the SDC entries the caller may use."""

from __future__ import annotations

from fleet.models import SensorType


def names(response) -> list[str]:
    assert response.status_code == 200, response.content
    return [entry["name"] for entry in response.json()["results"]]


def test_a_customer_sees_its_catalog_as_vv_sensor_list_shows_it(api_a) -> None:
    body = api_a.get("/api/v1/sensors/").json()
    entries = {e["name"]: e for e in body["results"]}
    assert "Battery" not in entries and {"CO2", "GPS", "Camera 640x480"} <= set(entries)
    assert entries["CO2"] == {
        "name": "CO2",
        "description": "CO2",
        "kind": "scalar",
        "unit": "ppm",
        "params": {"quantity": "co2"},
    }
    assert entries["Camera 640x480"]["params"]["width"] == 640


def test_allowed_sensors_and_privilege_shape_the_catalog(
    api_a, api_b, customer_a, customer_b
) -> None:
    customer_a.allowed_sensors.set(SensorType.objects.filter(name__in=["CO2", "Battery"]))
    assert names(api_a.get("/api/v1/sensors/")) == ["CO2"]
    customer_a.privileged = True
    customer_a.save()
    assert names(api_a.get("/api/v1/sensors/")) == ["Battery", "CO2"]
    assert "Thermometer" in names(api_b.get("/api/v1/sensors/"))


def test_staff_see_every_entry_with_its_privilege(api_staff) -> None:
    entries = {e["name"]: e for e in api_staff.get("/api/v1/sensors/").json()["results"]}
    assert entries["Battery"]["privileged"] is True and entries["CO2"]["privileged"] is False
    assert len(entries) == SensorType.objects.count()


def test_anonymous_callers_are_refused(client, db) -> None:
    assert client.get("/api/v1/sensors/").status_code in (401, 403)
