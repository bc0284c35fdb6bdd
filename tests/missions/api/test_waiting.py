"""Why a VV waits, as its owner reads it on its page, in the API (``waiting``) and in its log:
no vehicle in service covers its next task, its place in the queue, the RV flying to its task
with the plan's estimate; on discrete-event time with the in-process platform."""

from __future__ import annotations

import re
import time

import pytest

from fleet.models import VehicleStatus
from missions.models import LogEntry, VirtualVehicle, VVStatus
from tests.factories import AREA_TWO
from vvm_worker.clock import SIM_EPOCH_S
from vvm_worker.services import vehicle_create, vehicle_set_status, vv_submit

PROGRAM = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(%s, %s, 50), tolerance: 2,
                 sensors: [co2]});
VV.log('read');
"""
NO_VEHICLE = (
    "no vehicle in service covers the next task at 48.111100, 12.861900, 50 m; "
    "it continues when one does"
)


def program(lat: float = 48.1111, lng: float = 12.8619) -> str:
    return PROGRAM % (lat, lng)


def log_of(vv: VirtualVehicle) -> list[str]:
    return list(
        LogEntry.objects.filter(vv=vv).order_by("at_s", "id").values_list("message", flat=True)
    )


def waiting_of(api, vv: VirtualVehicle) -> dict | None:
    response = api.get(f"/api/v1/vvs/{vv.pk}/")
    assert response.status_code == 200, response.content
    return response.json()["waiting"]


def test_a_vv_whose_only_rv_goes_into_maintenance_says_why_it_waits_and_how_long_it_did(
    platform, fleet_one, customer_a, user_a, api_a, api_b, client
) -> None:
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=platform.vvm)
    platform.drain(until=VirtualVehicle.objects.filter(pk=vv.pk, host_rv=fleet_one).exists)
    assert waiting_of(api_a, vv)["reason"] == "flying"

    vehicle_set_status(vehicle=fleet_one, status=VehicleStatus.MAINTENANCE, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.RUNNING and vv.host_gs is not None and vv.pending is not None
    waiting = waiting_of(api_a, vv)
    assert waiting["reason"] == "no_vehicle" and waiting["message"] == NO_VEHICLE
    assert waiting["next_task_eta_s"] is None
    since_s = vv.waiting_since_s
    assert since_s is not None and waiting["since"] is not None
    assert log_of(vv) == [f"waiting: {NO_VEHICLE}"]
    assert api_b.get(f"/api/v1/vvs/{vv.pk}/").status_code == 404
    # The VV's page says it too, in the customer's words (no vehicle named).
    client.force_login(user_a)
    page = client.get(f"/vvs/{vv.pk}/").content.decode()
    assert NO_VEHICLE in page and "Heli One" not in page

    # 90 s later the RV is back in service: the VV flies on, and its log says how long it waited.
    platform.clock.t = since_s + 90
    vehicle_set_status(vehicle=fleet_one, status=VehicleStatus.ACTIVE, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert log_of(vv) == [f"waiting: {NO_VEHICLE}", "continues: waited 90 s", "read"]
    assert not vv.waiting_reason and vv.waiting_since_s is None
    assert waiting_of(api_a, vv) is None


def test_a_waiting_vv_logs_and_writes_its_reason_once_however_often_it_is_routed_again(
    platform, fleet_one, customer_a, api_a
) -> None:
    vehicle_set_status(vehicle=fleet_one, status=VehicleStatus.MAINTENANCE, vvm=platform.vvm)
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=platform.vvm)
    platform.drain()
    # Each fleet change routes the waiting VVs again: an RV elsewhere comes into service.
    for n in range(2):
        other = vehicle_create(
            config={
                "name": f"Elsewhere {n}",
                "depot_lat": 48.111,
                "depot_lng": 12.866,
                "area": AREA_TWO,
                "max_altitude_m": 120.0,
                "max_speed_mps": 10.0,
            },
            sensors=["CO2"],
            vvm=platform.vvm,
        )
        platform.add_vehicle_loop(other)
        platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.RUNNING and vv.waiting_reason == "no_vehicle"
    assert log_of(vv) == [f"waiting: {NO_VEHICLE}"]
    assert waiting_of(api_a, vv)["message"] == NO_VEHICLE


def test_a_queued_vv_says_how_many_of_its_customers_vvs_go_first_and_the_limit(
    customer_a, customer_b, ground_station, vvm_factory, api_a
) -> None:
    vvm = vvm_factory()  # nothing runs: the VVs stay where admission puts them
    customer_a.max_parallel_vvs = 1
    customer_a.save()
    vv_submit(customer=customer_b, name="B's", program=program(), vvm=vvm)  # not A's queue
    running, second, third = (
        vv_submit(customer=customer_a, name=name, program=program(), vvm=vvm)
        for name in ("first", "second", "third")
    )
    assert running.status == VVStatus.RUNNING
    assert second.status == third.status == VVStatus.QUEUED
    expected = {
        "first": None,
        "second": "in the queue behind 1 of your VVs (limit 1 in parallel)",
        "third": "in the queue behind 2 of your VVs (limit 1 in parallel)",
    }
    one = {vv.name: waiting_of(api_a, vv) for vv in (running, second, third)}
    assert {name: w and w["message"] for name, w in one.items()} == expected
    assert one["second"]["reason"] == "queue" and one["second"]["since"] is not None
    # A list says the same (its queued VVs' places read at once).
    listed = {vv["name"]: vv["waiting"] for vv in api_a.get("/api/v1/vvs/").json()["results"]}
    assert listed == one
    # With a larger limit, the second would start as soon as a ground station takes it.
    customer_a.max_parallel_vvs = 2
    customer_a.save()
    assert waiting_of(api_a, second)["message"] == "in the queue, about to start"
    assert waiting_of(api_a, third)["message"].startswith("in the queue behind 2 of your VVs")


def test_a_vv_on_an_rv_flying_to_its_task_says_when_it_gets_there_by_the_rvs_plan(
    platform, fleet_one, customer_a, api_a
) -> None:
    # The simulated clock on wall time: the API's "now" is the platform's.
    platform.clock.t = time.time() - SIM_EPOCH_S
    first = vv_submit(customer=customer_a, name="first", program=program(), vvm=platform.vvm)
    second = vv_submit(
        customer=customer_a, name="second", program=program(48.1125, 12.8605), vvm=platform.vvm
    )
    platform.drain(
        until=lambda: (
            VirtualVehicle.objects.filter(
                pk__in=[first.pk, second.pk], next_task_eta_s__isnull=False
            ).count()
            == 2
        )
    )
    now_s = platform.clock.t
    etas = {}
    for vv in (first, second):
        vv.refresh_from_db()
        waiting = waiting_of(api_a, vv)
        assert waiting["reason"] == "flying" and waiting["since"] is None
        left_s = vv.next_task_eta_s - now_s
        assert left_s > 10  # a flight from the depot, not an instant
        assert abs(waiting["next_task_eta_s"] - left_s) <= 2  # (the wall time of the test)
        assert re.fullmatch(r"flying to your task, about \d+ (s|min)", waiting["message"])
        etas[vv.name] = vv.next_task_eta_s
    assert etas["first"] != etas["second"]  # one after the other, on the RV's route
    platform.drain()
    # The plan's estimates held: each task was read when its estimate said.
    for vv in (first, second):
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED
        assert vv.tasks.get().done_s == pytest.approx(etas[vv.name], abs=0.5)
        assert waiting_of(api_a, vv) is None


RECEIVER = """
var got = VV.message.receive(%s);
VV.storage.store('got', got === null ? 'nothing' : got.value);
"""


def _receiving(vv: VirtualVehicle) -> bool:
    return (VirtualVehicle.objects.get(pk=vv.pk).pending or {}).get("kind") == "message"


def test_a_vv_waiting_for_a_message_says_so_and_at_most_how_long_it_still_waits(
    platform, ground_station, customer_a, user_a, api_a, client
) -> None:
    # The simulated clock on wall time: the API's "now" is the platform's.
    platform.clock.t = time.time() - SIM_EPOCH_S
    vv = vv_submit(customer=customer_a, name="Listener", program=RECEIVER % 600, vvm=platform.vvm)
    platform.drain(until=lambda: _receiving(vv))
    vv.refresh_from_db()
    assert vv.status == VVStatus.RUNNING and vv.host_gs is not None

    waiting = waiting_of(api_a, vv)
    assert waiting["reason"] == "message" and waiting["next_task_eta_s"] is None
    match = re.fullmatch(r"waiting for a message, at most (\d+) min more", waiting["message"])
    assert match and 9 <= int(match[1]) <= 10, waiting["message"]
    started = vv.platform_datetime(vv.pending["until_s"] - 600)
    assert waiting["since"] == started.isoformat().replace("+00:00", "Z")
    # A list says the same (read from the rows of a page), and so does the VV's page.
    (listed,) = api_a.get("/api/v1/vvs/").json()["results"]
    assert listed["waiting"] == waiting
    client.force_login(user_a)
    assert waiting["message"] in client.get(f"/vvs/{vv.pk}/").content.decode()

    # A message from the customer's own system: it takes it and goes on to its end.
    sent = api_a.post(f"/api/v1/vvs/{vv.pk}/messages/", {"value": [1, 2]}, format="json")
    assert sent.status_code == 201, sent.content
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert vv.storage.get(key="got").value == [1, 2]
    assert waiting_of(api_a, vv) is None
    (shown,) = api_a.get(f"/api/v1/vvs/{vv.pk}/messages/").json()["results"]
    assert shown["from"] is None and shown["received_at"] is not None


def test_a_message_wait_near_its_timeout_counts_seconds_and_one_not_timed_yet_says_no_time(
    customer_a, ground_station, vvm_factory, api_a
) -> None:
    vv = vv_submit(customer=customer_a, name="L", program="var a = 1;", vvm=vvm_factory())
    now_s = time.time() - vv.platform_offset_s
    receive = {"kind": "message", "q": 3, "tasks": [], "open": [], "timeout_s": 60.0}

    def waits(**more: float) -> dict:
        VirtualVehicle.objects.filter(pk=vv.pk).update(
            status=VVStatus.RUNNING, pending={**receive, **more}
        )
        return waiting_of(api_a, vv)

    # Before the host has looked for a message, its wait has no end yet.
    assert waits() == {
        "reason": "message",
        "message": "waiting for a message",
        "since": None,
        "next_task_eta_s": None,
    }
    soon = waits(until_s=now_s + 40.4)["message"]
    assert re.fullmatch(r"waiting for a message, at most (40|39) s more", soon)
    assert waits(until_s=now_s - 5)["message"] == "waiting for a message, at most 0 s more"
