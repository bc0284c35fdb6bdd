"""Batteries and maintenance (issue 58): the cycle rule, a battery swap, maintenance intervals
that ground an RV when overdue (its VVs move on) until someone records the maintenance, a
retired battery that grounds its RV until it is swapped, and the fleet overview's warnings."""

from __future__ import annotations

import datetime as dt

import pytest
from auditlog.models import LogEntry
from django.contrib.auth.models import Group
from django.core.exceptions import ValidationError
from django.utils import timezone

import fleet.admin
from accounts.roles import FLEET_MANAGER
from fleet.maintenance import cycle_step, vehicle_maintenance
from fleet.models import (
    Battery,
    Flight,
    MaintenanceInterval,
    MaintenanceRecord,
    VehicleKind,
    VehicleStatus,
)
from missions.models import VirtualVehicle, VVStatus
from tests.factories import CustomerFactory, UserFactory, VehicleFactory
from vvm_worker.services import (
    battery_observe,
    battery_swap,
    maintenance_record,
    vehicle_check_maintenance,
    vehicle_record_health,
    vehicle_set_status,
    vehicles_check_maintenance,
)

pytestmark = pytest.mark.django_db

NOW = timezone.now()


def flown(vehicle, n: int, *, minutes: float = 10.0, start=None):
    """``n`` landed flights of ``vehicle`` of ``minutes`` each, one an hour from ``start``."""
    start = start or NOW - dt.timedelta(hours=n + 1)
    for i in range(n):
        began = start + dt.timedelta(hours=i)
        Flight.objects.create(
            vehicle=vehicle,
            started=began,
            started_s=0.0,
            ended=began + dt.timedelta(minutes=minutes),
            duration_s=minutes * 60,
        )


def aboard(vehicle) -> VirtualVehicle:
    return VirtualVehicle.objects.create(
        customer=CustomerFactory(),
        name="VV",
        program="VV.log('x')",
        seed=7,
        start_ms=0,
        catalog=[],
        pending={"q": 3, "kind": "single", "tasks": []},
        submitted_s=1.5,
        status=VVStatus.RUNNING,
        host_rv=vehicle,
    )


@pytest.fixture
def manager(db):
    user = UserFactory(username="fm", is_staff=True)
    user.groups.add(Group.objects.get(name=FLEET_MANAGER))
    return user


def observe(vehicle, *pcts: float, **ids) -> list[bool]:
    return [battery_observe(vehicle_id=vehicle.pk, pct=p, now=NOW, **ids) for p in pcts]


# --- the cycle rule -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pcts", "cycles"),
    [
        ([100, 80, 60, 95], 0),  # never below 50 %
        ([100, 45, 95], 1),
        ([100, 45, 30, 60, 91], 1),  # once below 50 % counts once, however low
        ([45, 95, 96, 100, 95], 1),  # above 90 % again without a low one: no more
        ([45, 95, 40, 92, 49, 50, 93], 3),
        ([45, 90, 89], 0),  # 90 % is not above 90 %
        ([50, 95], 0),  # 50 % is not below 50 %
    ],
)
def test_the_cycle_rule(pcts, cycles) -> None:
    below, counted = False, 0
    for pct in pcts:
        below, one = cycle_step(below_low=below, pct=pct)
        counted += one
    assert counted == cycles


def test_a_battery_is_made_from_the_reports_and_counts_cycles_and_its_lowest_charge() -> None:
    heli = VehicleFactory(name="Heli One")
    observe(heli, 100, 70, 45, 35, 60, 95, 80, 48, 100)
    battery = Battery.objects.get(vehicle=heli)
    assert (battery.name, battery.cycles, battery.lowest_pct) == ("Heli One battery", 2, 35.0)


def test_a_swap_that_shows_a_full_battery_after_a_low_one_counts_a_cycle() -> None:
    """mavsim's battery reset: the charge jumps from low to 100 %, the same battery (no id)."""
    heli = VehicleFactory(name="Heli One")
    vehicle_record_health(vehicle_id=heli.pk, health={"link": "up", "battery_pct": 100})
    vehicle_record_health(vehicle_id=heli.pk, health={"link": "up", "battery_pct": 25})
    vehicle_record_health(vehicle_id=heli.pk, health={"link": "up", "battery_pct": 100})
    battery = Battery.objects.get(vehicle=heli)
    assert (battery.cycles, battery.lowest_pct, battery.below_low) == (1, 25.0, False)


def test_nothing_is_written_when_nothing_changes(django_assert_num_queries) -> None:
    heli = VehicleFactory(name="Heli One")
    observe(heli, 80)
    with django_assert_num_queries(1):
        observe(heli, 85)  # one read: the same battery, nothing new
    with django_assert_num_queries(0):
        battery_observe(vehicle_id=heli.pk, pct=None, now=NOW)


def test_the_autopilots_battery_id_and_serial_name_the_battery_and_another_is_a_swap() -> None:
    heli = VehicleFactory(name="Heli One")
    assert observe(heli, 90, battery_id=0) == [True]  # the first seen: made, and put in
    first = Battery.objects.get(vehicle=heli)
    assert (first.name, first.autopilot_id) == ("Heli One battery 0", 0)
    assert observe(heli, 100, battery_id=1) == [True]
    assert Battery.objects.get(vehicle=heli).name == "Heli One battery 1"
    assert observe(heli, 100, serial="SN-7") == [True]
    assert Battery.objects.get(vehicle=heli).serial == "SN-7"
    assert Battery.objects.filter(vehicle__isnull=True).count() == 2


# --- intervals that ground --------------------------------------------------------------------


def test_an_overdue_interval_grounds_the_rv_its_vvs_move_on_and_recording_returns_it(
    vvm_factory, manager
) -> None:
    vvm = vvm_factory()
    heli = VehicleFactory(name="Heli One")
    every_two = MaintenanceInterval.objects.create(name="2-flight check", every_flights=2)
    vv = aboard(heli)
    flown(heli, 1)
    due = vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    assert (due.overdue, due.grounding) == ([], None)
    flown(heli, 1, start=NOW - dt.timedelta(minutes=30))
    due = vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    assert [(d.name, d.kind, d.used, d.limit) for d in due.overdue] == [
        ("2-flight check", "flights", 2, 2)
    ]
    heli.refresh_from_db()
    assert heli.status == VehicleStatus.MAINTENANCE
    assert heli.status_reason == "grounded: 2-flight check overdue"
    assert vvm.dispatcher.arrived == [vv.pk], "the VVs aboard move on"

    record = maintenance_record(
        vehicle=heli, interval=every_two, by=manager, notes="props checked", vvm=vvm
    )
    heli.refresh_from_db()
    assert (heli.status, heli.status_reason) == (VehicleStatus.ACTIVE, "back in service: its "
                                                  "maintenance was recorded")  # fmt: skip
    assert (record.what, record.by_name, record.notes) == ("2-flight check", "fm", "props checked")
    assert LogEntry.objects.get_for_object(record).filter(action=LogEntry.Action.CREATE).exists()
    assert vehicle_maintenance(vehicle=heli, now=timezone.now()).overdue == []


def test_a_persons_maintenance_is_never_lifted_by_the_platform(vvm_factory, manager) -> None:
    vvm = vvm_factory()
    heli = VehicleFactory(name="Heli One")
    vehicle_set_status(vehicle=heli, status=VehicleStatus.MAINTENANCE, vvm=vvm, reason="rotor")
    maintenance_record(vehicle=heli, by=manager, what="looked at it", notes="", vvm=vvm)
    heli.refresh_from_db()
    assert (heli.status, heli.status_reason) == (VehicleStatus.MAINTENANCE, "rotor")


def test_due_soon_at_90_percent_of_hours_and_days_count_since_the_first_flight(
    vvm_factory,
) -> None:
    heli = VehicleFactory(name="Heli One")
    rover = VehicleFactory(name="Rover", kind=VehicleKind.GROUND, min_altitude_m=0,
                           max_altitude_m=0, max_speed_mps=2)  # fmt: skip
    MaintenanceInterval.objects.create(name="1-hour inspection", every_hours=1.0, kind="aerial")
    MaintenanceInterval.objects.create(name="Monthly", every_days=30, vehicle=rover)
    flown(heli, 6, minutes=9.0)  # 54 minutes: 90 %
    flown(rover, 1, start=NOW - dt.timedelta(days=28))
    heli_due = vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm_factory())
    assert [(d.name, d.kind, d.used, d.limit) for d in heli_due.due_soon] == [
        ("1-hour inspection", "hours", 0.9, 1.0)
    ]
    rover_due = vehicle_maintenance(vehicle=rover, now=NOW)
    assert [(d.name, d.kind) for d in rover_due.due_soon] == [("Monthly", "days")]
    # Two days on, the daily look grounds the rover (and only the rover).
    later = NOW + dt.timedelta(days=2)
    assert vehicles_check_maintenance(vvm=vvm_factory(), now=later) == ["Rover"]
    rover.refresh_from_db()
    assert rover.status_reason == "grounded: Monthly overdue"


def test_an_interval_is_for_a_kind_or_a_vehicle_with_a_limit() -> None:
    heli = VehicleFactory(name="Heli One")
    with pytest.raises(ValidationError):
        MaintenanceInterval(name="x", kind="aerial", vehicle=heli, every_days=1).full_clean()
    with pytest.raises(ValidationError):
        MaintenanceInterval(name="x").full_clean()


# --- a battery's retirement ---------------------------------------------------------------------


def test_a_retired_battery_grounds_its_rv_and_a_swap_lifts_it(vvm_factory, manager) -> None:
    vvm = vvm_factory()
    heli = VehicleFactory(name="Heli One")
    MaintenanceInterval.objects.create(name="Packs", every_cycles=2, retire_cycles=3)
    observe(heli, 40, 95, 40)  # the battery is seen (put in now): one cycle
    flown(heli, 2, start=NOW + dt.timedelta(minutes=1))
    due = vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    assert (due.due_soon, due.overdue) == ([], [])
    assert observe(heli, 95) == [False]
    due = vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    assert [(d.kind, d.used, d.limit, d.battery) for d in due.overdue] == [
        ("cycles", 2, 2, "Heli One battery")
    ]
    assert due.grounding == "grounded: Packs overdue"
    assert observe(heli, 40, 95) == [False, True], "the third cycle retires it"
    battery = Battery.objects.get(vehicle=heli)
    assert battery.retired is not None and battery.cycles == 3
    assert battery.flights == 2
    assert Flight.objects.filter(vehicle=heli, battery_name="Heli One battery").count() == 2

    vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    heli.refresh_from_db()
    assert heli.status == VehicleStatus.MAINTENANCE
    assert heli.status_reason == "battery Heli One battery retired: swap it"
    with pytest.raises(ValidationError, match="retired"):
        battery_swap(vehicle=heli, name="Heli One battery", by=manager, vvm=vvm)

    fresh = battery_swap(vehicle=heli, name="Pack 7", by=manager, vvm=vvm)
    heli.refresh_from_db()
    assert (fresh.vehicle_id, fresh.cycles) == (heli.pk, 0)
    assert heli.status == VehicleStatus.ACTIVE
    assert Battery.objects.get(name="Heli One battery").vehicle is None
    swap = MaintenanceRecord.objects.get(battery=fresh)
    assert (swap.what, swap.by_name) == ("battery swapped: Pack 7", "fm")


def test_the_autopilot_reporting_another_battery_is_a_swap_that_lifts_the_grounding(
    vvm_factory,
) -> None:
    vvm = vvm_factory()
    heli = VehicleFactory(name="Heli One")
    MaintenanceInterval.objects.create(name="Packs", retire_cycles=1)
    assert observe(heli, 40, 95, battery_id=0) == [True, True]  # put in; retired
    vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    heli.refresh_from_db()
    assert heli.status_reason == "battery Heli One battery 0 retired: swap it"
    assert observe(heli, 100, battery_id=1) == [True]  # the caller checks again:
    vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    heli.refresh_from_db()
    assert heli.status == VehicleStatus.ACTIVE


# --- the fleet overview -------------------------------------------------------------------------


def test_the_fleet_overview_warns_of_maintenance_due_soon_and_overdue(
    client, manager, vvm_factory, monkeypatch
) -> None:
    monkeypatch.setattr(fleet.admin, "platform_vvm", vvm_factory)
    heli = VehicleFactory(name="Heli One")
    other = VehicleFactory(name="Heli Two")
    MaintenanceInterval.objects.create(name="10-flight check", every_flights=10)
    flown(heli, 9)
    flown(other, 10)
    client.force_login(manager)
    page = client.get("/admin/fleet/vehicle/overview/").content.decode()
    assert "Due soon:</strong> 10-flight check: 9 of 10 flights" in page
    assert "Overdue:</strong> 10-flight check: 10 of 10 flights" in page


def test_maintenance_is_recorded_in_the_admin_through_the_service(
    client, manager, vvm_factory, monkeypatch
) -> None:
    vvm = vvm_factory()
    monkeypatch.setattr(fleet.admin, "platform_vvm", lambda: vvm)
    heli = VehicleFactory(name="Heli One")
    check = MaintenanceInterval.objects.create(name="2-flight check", every_flights=2)
    flown(heli, 2)
    vehicle_check_maintenance(vehicle_id=heli.pk, vvm=vvm)
    client.force_login(manager)
    response = client.post(
        "/admin/fleet/maintenancerecord/add/",
        {"vehicle": heli.pk, "interval": check.pk, "what": "", "notes": "ok", "swap_to": ""},
    )
    assert response.status_code == 302, response.content.decode()[:2000]
    heli.refresh_from_db()
    assert heli.status == VehicleStatus.ACTIVE
    swapped = client.post(
        "/admin/fleet/maintenancerecord/add/",
        {"vehicle": heli.pk, "what": "", "notes": "", "swap_to": "Pack 9"},
    )
    assert swapped.status_code == 302
    assert Battery.objects.get(name="Pack 9").vehicle == heli
