"""Batteries: an RV plans only what it can fly with its reserve left, hands its work over when
it runs low, recharges at its depot and comes back; customers notice nothing but time."""

from __future__ import annotations

from typing import Any

import pytest

from fleet.simulation import SimVehicle
from missions.models import Migration, TaskStatus, VVStatus
from tests.factories import VehicleFactory
from vvm_worker.services import vv_submit

# Twelve points around area one (about 550 m x 370 m), 50 m up.
SURVEY = """
var co2 = VV.sensor.get('CO2');
for (var n = 0; n < 12; ++n) {
  var lat = 48.1095 + (n % 4) * 0.0013, lng = 12.8595 + Math.floor(n / 4) * 0.002;
  var d = VV.task.execute({type: 'point', tolerance: 2, sensors: [co2],
                           position: new VV.types.LatLngAlt(lat, lng, 50)});
  VV.storage.store('p' + n, d[0].value);
}
"""
BATTERY_S = 240.0
RESERVE = 0.2


@pytest.fixture
def short_batteries(settings, platform, ground_station):
    settings.CPCC_BATTERY_RESERVE = RESERVE
    settings.CPCC_RECHARGE_S = 120.0
    for name in ("Heli One", "Heli Two"):
        platform.add_vehicle_loop(VehicleFactory(name=name, battery_s=BATTERY_S))
    return platform


def _lowest_battery_s(driver) -> float:
    """The least endurance a simulated vehicle had left: at the end of one of its legs (the
    battery drains linearly while airborne)."""
    legs = driver.planned_legs(float("-inf"))
    return min(driver.battery_remaining_s(leg.end_s) for leg in legs)


def test_short_batteries_recharge_and_every_vv_finishes_with_every_reading_once(
    short_batteries, customer_a, customer_b
) -> None:
    platform = short_batteries
    vvs = [
        vv_submit(customer=customer, name=f"Survey {n}", program=SURVEY, vvm=platform.vvm)
        for n, customer in enumerate([customer_a, customer_b, customer_a])
    ]
    platform.drain()
    for vv in vvs:
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert vv.tasks.filter(status=TaskStatus.DONE).count() == 12
        assert sorted(vv.storage.values_list("key", flat=True)) == sorted(
            f"p{n}" for n in range(12)
        )
    charges = {pk: len(driver._charges) for pk, driver in _drivers(platform).items()}
    assert sum(charges.values()) >= 2, f"the batteries were recharged: {charges}"
    for driver in _drivers(platform).values():
        assert _lowest_battery_s(driver) >= RESERVE * BATTERY_S - 1e-6
    handed_over = Migration.objects.filter(from_kind="rv", to_kind__in=["rv", "gs"]).exclude(
        reason__in=["finished"]
    )
    assert handed_over.exists(), "VVs aboard an RV that ran low moved on"


def test_without_a_reserve_setting_the_battery_is_still_never_planned_empty(
    settings, platform, ground_station, customer_a
) -> None:
    settings.CPCC_BATTERY_RESERVE = 0.0
    settings.CPCC_RECHARGE_S = 60.0
    platform.add_vehicle_loop(VehicleFactory(name="Heli One", battery_s=BATTERY_S))
    vv = vv_submit(customer=customer_a, name="Survey", program=SURVEY, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    (driver,) = _drivers(platform).values()
    assert driver._charges, "one RV alone recharges and carries on"
    assert _lowest_battery_s(driver) >= 0.0


def _drivers(platform: Any) -> dict[int, SimVehicle]:
    drivers = {pk: rig.driver for pk, rig in platform.rigs.items()}
    assert all(isinstance(d, SimVehicle) for d in drivers.values())
    return drivers  # type: ignore[return-value]
