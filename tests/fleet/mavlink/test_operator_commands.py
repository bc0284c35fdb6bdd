"""An operator's "land now" and "return home now" reach a MAVLink autopilot (issue 26): the
driver sends MAV_CMD_NAV_LAND or MAV_CMD_NAV_RETURN_TO_LAUNCH to MavSim over loopback, and
the copter lands where it is, or at home."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from fleet.geo import distance_m, ground_distance_m, offset
from fleet.mavlink import MavlinkDriver, MavSim
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import DEPOT, SPEC, sim_clock, wait_until

SPEED = 40.0
TARGET = offset(DEPOT, north_m=-300, east_m=-200, up_m=40)


@pytest.fixture
def driver(port: int, make_sim: Callable[..., MavSim]) -> Iterator[tuple[MavlinkDriver, MavSim]]:
    sim = make_sim(speed=SPEED)
    flown = MavlinkDriver(
        f"udpout:127.0.0.1:{port}",
        spec=SPEC,
        depot=DEPOT,
        clock=sim_clock(SPEED),
        telemetry_hz=50.0,
        command_timeout_s=0.5,
    )
    flown.connect(timeout_s=5.0)
    yield flown, sim
    flown.close()


def _on_the_way(driver: MavlinkDriver) -> Any:
    clock = driver.clock
    driver.fly_to(TARGET, clock())
    wait_until(lambda: driver.phase_at(clock()) == "cruise", what="the cruise")
    wait_until(lambda: ground_distance_m(driver.position_at(clock()), DEPOT) > 80, what="away")
    return clock


def test_land_now_sends_nav_land_and_the_copter_lands_where_it_is(driver) -> None:
    flown, sim = driver
    clock = _on_the_way(flown)
    assert flown.speed_at(clock()) == pytest.approx(SPEC.max_speed_mps, rel=0.2)
    now = clock()
    here = flown.position_at(now)
    due = flown.land(now)
    assert due - now == pytest.approx((here.alt - DEPOT.alt) / SPEC.climb_rate_mps, abs=0.5)
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_LAND) == [0], "sent once, acknowledged"
    assert sim.mode == "LAND"
    assert flown.phase_at(clock()) == "landing"
    wait_until(lambda: sim.on_ground and not sim.armed, timeout=20, what="the landing")
    wait_until(lambda: flown.is_landed_at(clock()), what="the driver to see it landed")
    assert ground_distance_m(sim.position(), here) < 5.0, "where it was, not at home"
    assert ground_distance_m(sim.position(), DEPOT) > 70.0
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == []
    now = clock()
    assert flown.land(now) == now  # landed: nothing more is sent
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_LAND) == [0]


def test_return_home_sends_rtl_and_the_copter_lands_at_home(driver) -> None:
    flown, sim = driver
    clock = _on_the_way(flown)
    flown.return_to_depot(clock())
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == [0]
    assert sim.mode == "RTL"
    wait_until(lambda: sim.on_ground and not sim.armed, timeout=30, what="the landing at home")
    assert distance_m(sim.position(), DEPOT) < 2.0
    assert flown.speed_at(clock()) == 0.0
