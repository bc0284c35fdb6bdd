"""A pilot in command (issue 57): with CPCC_REQUIRE_PILOT an RV with no pilot on duty takes no
new work, its VVs wait saying so, and they go on when a pilot comes on duty; every flight is
recorded with the RV's pilot on duty at its take-off. On discrete-event time with the in-process
platform (``platform``), as the other waiting tests."""

from __future__ import annotations

import datetime as dt

import pytest
from django.contrib.auth.models import Group

from accounts.roles import PILOT
from fleet.models import Flight, VehicleStatus
from missions.models import LogEntry, VirtualVehicle, VVStatus
from missions.waiting import vv_waiting
from tests.api_fixtures import token_client
from tests.factories import UserFactory, VehicleFactory
from vvm_worker.clock import SIM_EPOCH_S
from vvm_worker.services import (
    vehicle_hand_over,
    vehicle_set_status,
    vehicle_take_duty,
    vv_submit,
)

NO_PILOT = (
    "no pilot on duty for the vehicles that cover its next task; it continues when one comes "
    "on duty"
)
ONE_TASK = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]});
VV.log('read');
"""
TWO_TASKS = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]});
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1121, 12.8617, 50),
                 tolerance: 2, sensors: [co2]});
VV.log('both read');
"""


@pytest.fixture
def fleet_one(platform, ground_station):
    """One RV (Heli One) with its control loop on the platform, no pilot on duty."""
    vehicle = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(vehicle)
    return vehicle


@pytest.fixture
def api_a(user_a):
    return token_client(user_a)


@pytest.fixture
def api_b(user_b):
    return token_client(user_b)


@pytest.fixture
def pilot(db):
    user = UserFactory(username="pilot-one", is_staff=True)
    user.groups.add(Group.objects.get(name=PILOT))
    return user


@pytest.fixture
def require_pilot(settings) -> None:
    settings.CPCC_REQUIRE_PILOT = True


def log_of(vv: VirtualVehicle) -> list[str]:
    rows = LogEntry.objects.filter(vv=vv).order_by("at_s", "id")
    return list(rows.values_list("message", flat=True))


def waiting_of(api, vv: VirtualVehicle) -> dict | None:
    response = api.get(f"/api/v1/vvs/{vv.pk}/")
    assert response.status_code == 200, response.content
    return response.json()["waiting"]


def test_an_rv_with_no_pilot_takes_no_work_until_one_comes_on_duty(
    require_pilot, platform, fleet_one, pilot, customer_a, api_a, api_b
) -> None:
    fleet_one.pilots.add(pilot)
    vv = vv_submit(customer=customer_a, name="VV", program=ONE_TASK, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    # It waits on the ground station: the RV, in service, has no pilot on duty.
    assert vv.status == VVStatus.RUNNING and vv.host_gs is not None and vv.host_rv is None
    assert not vv.tasks.filter(vehicle=fleet_one).exists()
    assert not Flight.objects.exists(), "the RV never took off"
    waiting = waiting_of(api_a, vv)
    assert (waiting["reason"], waiting["message"]) == ("no_pilot", NO_PILOT)
    assert waiting["since"] is not None
    assert vv_waiting(vv, tasks_open=1).reason == "no_pilot"
    assert log_of(vv) == [f"waiting: {NO_PILOT}"]
    assert api_b.get(f"/api/v1/vvs/{vv.pk}/").status_code == 404

    # 60 s later a pilot takes it on duty: the VV flies on and finishes.
    platform.clock.t = on_duty_s = vv.waiting_since_s + 60
    vehicle_take_duty(vehicles=[fleet_one], pilot=pilot, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert log_of(vv) == [f"waiting: {NO_PILOT}", "continues: waited 60 s", "read"]
    assert not vv.waiting_reason and waiting_of(api_a, vv) is None
    # Its take-off is recorded with its pilot in command.
    flight = Flight.objects.get()
    assert (flight.vehicle, flight.pilot, flight.pilot_name) == (
        fleet_one,
        pilot,
        "pilot-one",
    )
    assert flight.started_s == on_duty_s  # at once
    assert flight.started == dt.datetime.fromtimestamp(SIM_EPOCH_S + flight.started_s, tz=dt.UTC)
    # It landed at home: the flight closed with the task it served.
    assert (flight.ended_how, flight.tasks_served) == ("landed_home", 1)


def test_a_vv_aboard_an_rv_handed_over_to_nobody_waits_on_a_station_and_flies_on_with_a_pilot(
    require_pilot, platform, fleet_one, pilot, customer_a, api_a
) -> None:
    fleet_one.pilots.add(pilot)
    vehicle_take_duty(vehicles=[fleet_one], pilot=pilot, vvm=platform.vvm)
    vv = vv_submit(customer=customer_a, name="VV", program=TWO_TASKS, vvm=platform.vvm)
    loop = platform.rigs[fleet_one.pk].loop
    platform.drain(until=lambda: not loop.driver.is_landed_at(platform.clock.t))
    vv.refresh_from_db()
    assert vv.host_rv == fleet_one, "aboard, flying to its first task"

    # The pilot hands the RV over to nobody in flight: it serves the task it has, but its
    # VV's next task is new work, which it does not take: the VV waits on a station.
    vehicle_hand_over(vehicles=[fleet_one], by=pilot, to=None, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.RUNNING and vv.host_gs is not None, (vv.status, vv.host_rv)
    assert vv.tasks.filter(status="done").count() == 1
    assert vv.tasks.filter(status="open", vehicle__isnull=True).count() == 1
    assert waiting_of(api_a, vv)["reason"] == "no_pilot"

    vehicle_take_duty(vehicles=[fleet_one], pilot=pilot, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert log_of(vv)[-1] == "both read"
    # Both take-offs name the pilot in command then.
    assert list(Flight.objects.order_by("started_s").values_list("pilot_name", flat=True)) == [
        "pilot-one",
        "pilot-one",
    ]


def test_an_rv_in_maintenance_is_what_a_vv_waits_for_even_without_a_pilot(
    require_pilot, platform, fleet_one, customer_a, api_a
) -> None:
    vehicle_set_status(vehicle=fleet_one, status=VehicleStatus.MAINTENANCE, vvm=platform.vvm)
    vv = vv_submit(customer=customer_a, name="VV", program=ONE_TASK, vvm=platform.vvm)
    platform.drain()
    assert waiting_of(api_a, vv)["reason"] == "no_vehicle"


def test_without_the_setting_an_rv_with_no_pilot_flies_and_its_take_off_names_none(
    platform, fleet_one, customer_a, api_a
) -> None:
    vv = vv_submit(customer=customer_a, name="VV", program=ONE_TASK, vvm=platform.vvm)
    platform.drain(until=VirtualVehicle.objects.filter(pk=vv.pk, host_rv=fleet_one).exists)
    assert waiting_of(api_a, vv)["reason"] == "flying"
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED and not vv.waiting_reason
    assert "waiting" not in " ".join(log_of(vv))
    flight = Flight.objects.get()
    assert (flight.vehicle, flight.pilot, flight.pilot_name) == (fleet_one, None, "")


def test_an_rv_workers_take_off_goes_with_its_next_report_at_the_map_tick(
    vvm_factory, pilot
) -> None:
    # An RV worker's store writes a report that does not move the vehicle at the map tick:
    # the take-off it carries goes with it (the same commit), even when a later report
    # replaced it meanwhile, with the pilot on duty then; once.
    from vvm_worker.control import VehicleState
    from vvm_worker.executor import DatabaseStore

    vehicle = VehicleFactory(name="Heli One")
    vehicle.pilots.add(pilot)
    vvm = vvm_factory()
    vehicle_take_duty(vehicles=[vehicle], pilot=pilot, vvm=vvm)
    store = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm, ticks=True)

    def report(t_s: float, phase: str, took_off_s: float | None = None) -> VehicleState:
        return VehicleState(t_s, vehicle.depot, phase, 0.0, 0.0, {}, took_off_s=took_off_s)

    store.record_state(report(10.0, "landed"), moved=True)
    store.record_state(report(20.0, "takeoff", took_off_s=20.0), moved=False)
    store.record_state(report(20.5, "takeoff"), moved=False)
    assert not Flight.objects.exists(), "not before the tick"
    store.write_waiting()
    flight = Flight.objects.get()
    assert (flight.vehicle, flight.started_s, flight.pilot) == (vehicle, 20.0, pilot)
    assert flight.started == dt.datetime.fromtimestamp(SIM_EPOCH_S + 20.0, tz=dt.UTC)
    store.write_waiting()
    assert Flight.objects.count() == 1
