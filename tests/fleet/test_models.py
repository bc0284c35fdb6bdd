"""The SDC, ground stations and vehicles."""

from __future__ import annotations

import pytest
from django.core.exceptions import ValidationError
from django.db import IntegrityError

from fleet.catalog import DEFAULT_SDC
from fleet.geo import Position
from fleet.models import SensorType, Vehicle
from tests.factories import VehicleFactory


@pytest.mark.django_db
def test_the_default_catalog_is_seeded_by_a_migration() -> None:
    names = set(SensorType.objects.values_list("name", flat=True))
    assert {e["name"] for e in DEFAULT_SDC} <= names
    assert {
        "Altimeter",
        "Barometer",
        "Battery",
        "CO2",
        "GPS",
        "NOx",
        "Thermometer",
        "Camera 640x480",
        "Belly Mounted Camera 640x480",
        "FPV Camera 640x480",
    } <= names
    assert SensorType.objects.get(name="Battery").privileged
    camera = SensorType.objects.get(name="Camera 640x480")
    assert (camera.kind, camera.params["width"], camera.params["height"]) == ("camera", 640, 480)


def test_vehicle_area_covers_inside_and_border_but_not_outside(heli_one) -> None:
    assert heli_one.covers(Position(48.1111, 12.8619, 50))
    assert heli_one.covers(Position(48.111, 12.864, 50))  # on the border with Heli Two's area
    assert not heli_one.covers(Position(48.1111, 12.8667, 50))


def test_vehicle_position_is_its_depot_until_it_reports(heli_one) -> None:
    heli_one.lat = heli_one.lng = None
    assert heli_one.position == heli_one.depot


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("area", "words"),
    [
        ([[48.1, 12.1], [48.2, 12.1], [48.1, 12.1]], "at least 3 distinct points"),
        ([[48.1, 12.1], [48.2, 12.1], [48.2, 12.2], [48.1, 12.2]], "must be closed"),
        ([[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]], "not a valid polygon"),
    ],
)
def test_vehicle_clean_refuses_bad_areas(area, words) -> None:
    vehicle = VehicleFactory.build(name="Bad", area=area)
    with pytest.raises(ValidationError, match=words):
        vehicle.clean()


@pytest.mark.django_db
def test_vehicle_altitude_range_is_a_database_constraint() -> None:
    with pytest.raises(IntegrityError):
        VehicleFactory(name="Upside down", min_altitude_m=100, max_altitude_m=10)


def test_vehicle_sensors(heli_one) -> None:
    names = set(heli_one.sensors.values_list("name", flat=True))
    assert names == {"CO2", "Thermometer", "Camera 640x480", "GPS", "Barometer", "Altimeter", "NOx"}
    assert Vehicle.objects.get(name="Heli One").status == "active"
