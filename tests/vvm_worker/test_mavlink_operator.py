"""An operator's commands reach a MAVLink RV through its worker (issue 26): "land now" lands the
copter where it is (MAV_CMD_NAV_LAND), "return home now" takes it off again and home, where the
autopilot's RTL (MAV_CMD_NAV_RETURN_TO_LAUNCH) lands it. The worker runs in a process of its
own, as in production; the command goes as any fleet change does (database, then a message)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fleet.geo import distance_m, ground_distance_m
from fleet.mavlink.wire import mavlink
from fleet.models import Vehicle, VehicleCommand, VehicleStatus
from tests.conftest import SCENARIOS
from tests.polling import wait_until
from tests.vvm_worker.test_distributed import load
from tests.vvm_worker.test_mavlink_worker import _mavlink, _vv1_only, copters  # noqa: F401
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vehicle_command

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]


def test_land_now_then_return_home_reach_the_autopilot(
    workers,
    copters,  # noqa: F811 - the fixture
    tmp_path: Path,
    monkeypatch,
) -> None:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    load(_vv1_only(data["vehicles"]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    copters.append(sim := _mavlink(heli))
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_until(
        # (over the ground: a copter climbing above its depot is not away from home)
        lambda: not sim.on_ground and ground_distance_m(sim.position(), heli.depot) > 60,
        timeout=120,
        what="the copter on its way to VV 1's task",
        details=workers.logs,
    )

    asked = vehicle_command(
        vehicle=heli, command=VehicleCommand.LAND, vvm=platform_vvm(), reason="test: land"
    )
    assert asked.status == VehicleStatus.MAINTENANCE
    wait_until(
        lambda: sim.commands_seen(mavlink.MAV_CMD_NAV_LAND),
        timeout=30,
        what="MAV_CMD_NAV_LAND at the autopilot",
        details=workers.logs,
    )
    where = sim.position()
    wait_until(lambda: sim.on_ground and not sim.armed, timeout=60, what="the landing")
    assert ground_distance_m(sim.position(), where) < 20.0, "where it was"
    assert ground_distance_m(sim.position(), heli.depot) > 40.0, "not at home"
    heli.refresh_from_db()
    assert heli.command_taken is not None and heli.status == VehicleStatus.MAINTENANCE
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == []

    vehicle_command(
        vehicle=heli, command=VehicleCommand.RETURN_HOME, vvm=platform_vvm(), reason="test: home"
    )
    wait_until(
        lambda: sim.commands_seen(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH),
        timeout=60,
        what="MAV_CMD_NAV_RETURN_TO_LAUNCH at the autopilot",
        details=workers.logs,
    )
    wait_until(
        lambda: sim.on_ground and not sim.armed and distance_m(sim.position(), heli.depot) < 2,
        timeout=60,
        what="the copter home",
        details=workers.logs,
    )
    assert len(sim.commands_seen(mavlink.MAV_CMD_NAV_LAND)) == 1, "each command obeyed once"
    heli.refresh_from_db()
    assert heli.status == VehicleStatus.MAINTENANCE, "until an operator returns it to service"
