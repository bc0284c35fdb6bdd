"""What an RV's worker tells the live map for operators (issue 26: status and why, battery or
why not, speed, link and health, what it is doing, its next task, the operator's last command)
reaches staff sockets only: a customer's socket shows the carrier of its VVs as before."""

from __future__ import annotations

import time

import pytest
from asgiref.sync import sync_to_async

from fleet.simulation import SimVehicle, VehicleSpec
from missions.events import EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH
from tests.factories import VehicleFactory
from tests.missions.test_consumers import PROGRAM, _socket
from tests.vvm_worker.test_control_loop import DEPOT, Clock, Store
from vvm_worker.control import ControlLoop
from vvm_worker.live import FeedAnnouncer, publish_vehicle
from vvm_worker.planning import TravelTime, make_planner
from vvm_worker.services import vv_submit

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

# What HostedRV.beacon adds for operators to the loop's live state (vvm_worker/hosts.py).
FOR_OPERATORS = {
    "driver": "sim",
    "status_reason": "return home now: asked by operator on the fleet overview",
    "speed_mps": 9.5,
    "link": "simulated",
    "health": {"link": "simulated", "battery_pct": 80},
    "battery": 0.8,
    "battery_why": "",
}
# What a customer's map shows of a vehicle carrying one of its VVs (its kind: the symbol).
CARRIER_KEYS = {"id", "lat", "lng", "alt", "kind", "phase", "t", "vvs"}


@pytest.fixture(autouse=True)
async def _close_socket_connections():
    yield
    from channels.db import database_sync_to_async
    from django.db import connections

    await database_sync_to_async(connections.close_all)()


@pytest.fixture(autouse=True)
def feed(broker):
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)
    yield broker
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)


def _published(vehicle, vvs) -> dict:
    """A worker's state of ``vehicle`` carrying ``vvs``: the loop's live state (as a real loop
    says it) with what the worker adds for operators."""
    clock = Clock()
    loop = ControlLoop(
        name=vehicle.name,
        driver=SimVehicle(VehicleSpec(max_speed_mps=10.0), DEPOT),
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0)),
        store=Store(),
        scheduler=clock,
        clock=lambda: clock.now,
    )
    state = loop.live_state(0.0) | FOR_OPERATORS
    state["vvs"] = [{"id": str(vv.pk), "name": vv.name, "customer": vv.customer_id} for vv in vvs]
    return state | {"id": vehicle.pk, "name": vehicle.name, "t": time.time()}


async def test_operators_see_the_vehicles_whole_state_and_customers_only_their_carrier(
    client, staff, user_a, customer_a, customer_b, ground_station, vvm_factory
) -> None:
    vvm = vvm_factory()
    vvm.announcer = FeedAnnouncer()
    mine = await sync_to_async(vv_submit)(
        customer=customer_a, name="mine", program=PROGRAM, vvm=vvm
    )
    theirs = await sync_to_async(vv_submit)(
        customer=customer_b, name="theirs", program=PROGRAM, vvm=vvm
    )
    heli = await sync_to_async(VehicleFactory)(name="Heli One")
    state = _published(heli, [mine, theirs])
    assert {"activity", "next_task", "command", "status", "battery"} <= set(state)
    publish_vehicle(state)

    await sync_to_async(client.force_login)(staff)
    socket = _socket(client)
    assert (await socket.connect())[0]
    (shown,) = (await socket.receive_json_from(timeout=5))["vehicles"]
    await socket.disconnect()
    assert shown["name"] == "Heli One"
    assert {k: shown[k] for k in FOR_OPERATORS} == FOR_OPERATORS
    assert (shown["activity"], shown["next_task"], shown["command"]) == ("landed", None, None)

    await sync_to_async(client.force_login)(user_a)
    socket = _socket(client)
    assert (await socket.connect())[0]
    (carrier,) = (await socket.receive_json_from(timeout=5))["vehicles"]
    await socket.disconnect()
    assert set(carrier) == CARRIER_KEYS
    assert carrier["vvs"] == [{"id": str(mine.pk), "name": "mine", "customer": customer_a.pk}]
    assert "fleet overview" not in str(carrier) and "simulated" not in str(carrier)
