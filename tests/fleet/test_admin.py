"""The fleet's admin shows numbers as what they mean: positions to 6 decimals (about 0.1 m),
altitudes, distances and speeds to 0.1, durations to 0.1 s, never a float's every digit."""

from __future__ import annotations

from django.urls import reverse

from fleet.models import GroundStation, NoFlyZone, RallyPoint, Vehicle
from tests.admin_numbers import RAW_FLOAT, cells
from tests.factories import AREA_ONE, VehicleFactory


def test_a_vehicle_shows_its_state_rounded_to_what_it_means(client, staff) -> None:
    vehicle = VehicleFactory(name="Heli One")
    Vehicle.objects.filter(pk=vehicle.pk).update(
        lat=48.11123456789,
        lng=12.86191234567,
        alt=49.987654321,
        distance_m=6831.406656359808,
        flight_s=4093.2234567,
        max_speed_mps=12.345678,
    )
    client.force_login(staff)
    page = client.get(reverse("admin:fleet_vehicle_change", args=[vehicle.pk])).text
    shown = cells(page)
    for text in ("48.111235", "12.861912", "50.0 m", "6,831.4 m", "4,093.2 s (1:08:13)"):
        assert text in shown, text
    assert not RAW_FLOAT.search(shown), RAW_FLOAT.search(shown)
    listed = cells(client.get(reverse("admin:fleet_vehicle_changelist")).text)
    assert "12.3 m/s" in listed and not RAW_FLOAT.search(listed)


def test_stations_rally_points_and_zones_list_rounded_positions_and_altitudes(
    client, staff
) -> None:
    client.force_login(staff)
    GroundStation.objects.create(name="GS", lat=48.1134999999, lng=12.86000000001, alt=2.04999)
    RallyPoint.objects.create(name="RP", lat=48.11212121212, lng=12.8611111111, alt=19.96666)
    NoFlyZone.objects.create(
        name="Zone",
        area=[list(p) for p in AREA_ONE],
        min_altitude_m=0.333333333,
        max_altitude_m=120.0000001,
    )
    expected = {
        "groundstation": ("48.113500", "12.860000", "2.0 m"),
        "rallypoint": ("48.112121", "12.861111", "20.0 m"),
        "noflyzone": ("0.3 m", "120.0 m"),
    }
    for model, texts in expected.items():
        listed = cells(client.get(reverse(f"admin:fleet_{model}_changelist")).text)
        for text in texts:
            assert text in listed, (model, text)
        assert not RAW_FLOAT.search(listed), (model, RAW_FLOAT.search(listed))
