"""MavlinkDriver flying MavSim over loopback: what the RV control loop relies on."""

from __future__ import annotations

import inspect
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import (
    CommandTimeout,
    LinkLost,
    MavlinkDriver,
    MavSim,
    PreArmFailed,
    VehicleTookOver,
)
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import AREA, DEPOT, SPEC, sim_clock, wait_until

SPEED = 40.0  # a 300 m flight is under a second of the test
TELEMETRY_HZ = 50.0
# How late an arrival may be seen after the estimate, in simulated seconds: the take-off's end
# and the arrival are each noticed with the next position report, plus the link's latency.
LATE_S = 3 * SPEED / TELEMETRY_HZ
TARGET = offset(DEPOT, north_m=-200, east_m=-120, up_m=40)
SECOND = offset(DEPOT, north_m=-300, east_m=150, up_m=60)


@pytest.fixture
def make_driver(port: int) -> Iterator[Callable[..., MavlinkDriver]]:
    """Connected drivers for the test's MavSim (start the MavSim first), closed at the end."""
    drivers: list[MavlinkDriver] = []

    def make(**options: Any) -> MavlinkDriver:
        options.setdefault("spec", SPEC)
        options.setdefault("depot", DEPOT)
        options.setdefault("clock", sim_clock(SPEED))
        options.setdefault("telemetry_hz", TELEMETRY_HZ)
        options.setdefault("command_timeout_s", 0.5)
        driver = MavlinkDriver(f"udpout:127.0.0.1:{port}", **options)
        drivers.append(driver)
        driver.connect(timeout_s=5.0)
        return driver

    yield make
    for driver in drivers:
        driver.close()


def test_connect_asks_for_telemetry_and_uploads_the_geofence(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=SPEED)
    driver = make_driver(area=AREA, min_altitude_m=10.0, max_altitude_m=120.0)
    assert driver.link_ok and driver.is_landed_at(0.0)
    assert sim.message_interval_s(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT) == 1 / TELEMETRY_HZ
    for message in ("SYS_STATUS", "BATTERY_STATUS", "HEARTBEAT", "EXTENDED_SYS_STATE"):
        assert sim.message_interval_s(getattr(mavlink, f"MAVLINK_MSG_ID_{message}")) == 1.0

    # The fence MavSim received is the operation area (its closing point implied) ...
    assert sim.fence_polygons() == [[tuple(p) for p in AREA[:4]]]
    items = sim.mission_items()
    assert {i.command for i in items} == {mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION}
    assert {i.param1 for i in items} == {4.0}
    # ... with the altitude ceiling, and the fence on.
    assert sim.param("FENCE_ALT_MAX") == 120.0
    assert int(sim.param("FENCE_TYPE")) & (1 | 2 | 4) == 5  # altitude and polygon, no circle
    assert sim.param("FENCE_ENABLE") == 1.0
    assert driver.fence is not None and driver.fence[1:3] == (10.0, 120.0)

    # The area changes: upload again.
    smaller = [[48.110, 12.860], [48.110, 12.862], [48.112, 12.862], [48.110, 12.860]]
    driver.upload_fence(smaller, 10.0, 90.0)
    assert sim.fence_polygons() == [[tuple(p) for p in smaller[:3]]]
    assert sim.param("FENCE_ALT_MAX") == 90.0


def test_a_flight_out_and_home(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=SPEED)
    driver = make_driver()
    clock = driver.clock
    assert driver.battery_fraction() == 1.0

    start = clock()
    eta = driver.fly_to(TARGET, start)
    # Vertical take-off to 40 m, then 233 m at 10 m/s: the simulator's kinematics.
    assert eta - start == pytest.approx(40 / 3 + distance_m(DEPOT, TARGET.with_alt(0)) / 10)
    wait_until(lambda: driver.phase_at(clock()) == "takeoff", what="the take-off")
    assert sim.armed and sim.mode == "GUIDED"
    wait_until(lambda: driver.has_arrived(TARGET, 1.0), what="the arrival")
    # It arrives when the estimate says, give or take the telemetry's and the link's latency.
    assert clock() == pytest.approx(eta, abs=LATE_S)
    assert driver.phase_at(clock()) == "hovering"
    assert distance_m(driver.position_at(clock()), TARGET) < 1.0
    assert not driver.has_arrived(SECOND, 5.0)

    # Airborne, the next target is one straight leg.
    now = clock()
    eta = driver.fly_to(SECOND, now)
    assert eta - now == pytest.approx(driver.time_to_s(SECOND, now), abs=0.5)
    wait_until(lambda: driver.phase_at(clock()) == "cruise", what="the cruise")
    wait_until(lambda: driver.has_arrived(SECOND, 1.0), what="the second arrival")
    assert clock() == pytest.approx(eta, abs=LATE_S)

    now = clock()
    landing = driver.return_to_depot(now)
    assert landing - now == pytest.approx(driver.time_home_s(SECOND), abs=0.5)
    wait_until(lambda: driver.phase_at(clock()) == "landing", what="the descent at home")
    wait_until(lambda: driver.is_landed_at(clock()), what="the landing")
    assert clock() == pytest.approx(landing, abs=LATE_S)
    assert not sim.armed and sim.mode == "RTL"
    # The disarming heartbeat may come before the last position report.
    wait_until(lambda: distance_m(driver.position_at(clock()), DEPOT) < 0.1, what="home")
    now = clock()
    assert driver.return_to_depot(now) == now  # landed: nothing to do

    # Odometer and flight time from telemetry, against what the simulated copter flew.
    path = (
        distance_m(DEPOT, DEPOT.with_alt(40))
        + distance_m(DEPOT.with_alt(40), TARGET)
        + distance_m(TARGET, SECOND)
        + distance_m(SECOND, DEPOT.with_alt(60))
        + 60
    )
    assert driver.distance_m(clock()) == pytest.approx(path, rel=0.05)
    assert driver.flight_s(clock()) == pytest.approx(sim.flight_s(), abs=3.0)


def test_the_battery_drains_in_flight(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    make_sim(speed=SPEED)
    driver = make_driver()
    clock = driver.clock
    assert driver.battery_fraction() == 1.0
    assert driver.battery_remaining_s(clock()) == SPEC.battery_s
    driver.fly_to(TARGET, clock())
    wait_until(lambda: driver.has_arrived(TARGET, 1.0), what="the arrival")
    # About 37 s of a 600 s battery are gone (reported in whole percent, at 1 Hz).
    fraction = wait_until(
        lambda: (f := driver.battery_fraction()) is not None and f <= 0.94 and f,
        what="the battery to drop",
    )
    assert fraction >= 0.85
    assert driver.battery_remaining_s(clock()) == pytest.approx(fraction * SPEC.battery_s)


def test_a_refused_arming_says_why(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=SPEED, battery=0.15)
    driver = make_driver()
    with pytest.raises(PreArmFailed) as caught:
        driver.fly_to(TARGET, driver.clock())
    assert caught.value.lines == ["PreArm: Battery 1 below minimum arming capacity"]
    assert "Battery 1 below minimum arming capacity" in str(caught.value)
    assert not caught.value.permanent
    assert not sim.armed and driver.is_landed_at(driver.clock())

    sim.set_battery(1.0)
    sim.fail_prearm("Compass not calibrated")
    with pytest.raises(PreArmFailed, match="PreArm: Compass not calibrated"):
        driver.fly_to(TARGET, driver.clock())


def test_a_command_never_acknowledged_is_retried_then_reported(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=SPEED)
    driver = make_driver(command_timeout_s=0.25)
    sim.ignore_command(mavlink.MAV_CMD_NAV_TAKEOFF)
    with pytest.raises(CommandTimeout) as caught:
        driver.fly_to(TARGET, driver.clock())
    assert caught.value.command == mavlink.MAV_CMD_NAV_TAKEOFF
    assert not caught.value.permanent
    # Sent three times, the retransmissions numbered by `confirmation`.
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_TAKEOFF) == [0, 1, 2]
    # The driver does not leave the motors armed on the ground.
    assert not sim.armed and sim.on_ground
    wait_until(lambda: driver.is_landed_at(driver.clock()), what="the driver to see it")


def test_link_loss_in_flight(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=SPEED)
    lost = threading.Event()
    driver = make_driver(link_timeout_s=1.5, on_link_lost=lost.set)
    clock = driver.clock
    driver.fly_to(TARGET, clock())
    wait_until(lambda: driver.phase_at(clock()) == "cruise", what="the cruise")
    sim.cut_link()
    cut = time.monotonic()
    assert lost.wait(5.0)
    # The vehicle's last heartbeat came at most a second before the cut.
    assert 0.4 < time.monotonic() - cut < 1.5 + 0.25
    assert not driver.link_ok
    with pytest.raises(LinkLost) as caught:
        driver.fly_to(SECOND, clock())
    assert not caught.value.permanent
    with pytest.raises(LinkLost):
        driver.return_to_depot(clock())


def test_a_pilot_or_failsafe_taking_over_is_not_fought(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver], port: int
) -> None:
    sim = make_sim(speed=SPEED)
    driver = make_driver()
    clock = driver.clock
    driver.fly_to(TARGET, clock())
    wait_until(lambda: driver.phase_at(clock()) == "cruise", what="the cruise")

    pilot = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=254)
    try:
        pilot.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        pilot.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 9, 0, 0, 0, 0, 0)
        wait_until(lambda: sim.mode == "LAND", what="the pilot's LAND")
    finally:
        pilot.close()
    wait_until(lambda: driver.took_over == "LAND", what="the driver to notice")
    with pytest.raises(VehicleTookOver) as caught:
        driver.fly_to(SECOND, clock())
    assert caught.value.mode == "LAND" and caught.value.permanent
    # Landing by itself is a way home: the driver lets it land.
    driver.return_to_depot(clock())
    wait_until(lambda: driver.is_landed_at(clock()), what="the landing")
    assert not sim.armed and sim.mode == "LAND"
    assert driver.took_over is None  # disarmed: the next flight is the driver's again


def test_a_px4_copter_flies_in_offboard_mode(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=SPEED, autopilot="px4", ground_amsl_m=480.0)
    driver = make_driver(area=AREA, max_altitude_m=100.0)
    assert driver.autopilot.value == "px4"
    assert sim.param("GF_MAX_VER_DIST") == 100.0
    assert sim.param("GF_ACTION") == 2.0  # already acting on a breach: left as it is
    assert sim.fence_polygons() == [[tuple(p) for p in AREA[:4]]]

    clock = driver.clock
    driver.fly_to(TARGET, clock())
    wait_until(lambda: sim.mode == "AUTO.TAKEOFF", what="PX4's take-off mode")
    wait_until(lambda: sim.mode == "OFFBOARD", what="offboard")
    wait_until(lambda: driver.has_arrived(TARGET, 1.0), what="the arrival")
    driver.fly_to(SECOND, clock())
    wait_until(lambda: driver.has_arrived(SECOND, 1.0), what="the second arrival")
    assert sim.mode == "OFFBOARD"
    driver.return_to_depot(clock())
    wait_until(lambda: driver.is_landed_at(clock()), what="the landing")
    assert sim.mode == "AUTO.RTL" and not sim.armed
    assert distance_m(sim.position(), DEPOT) < 0.5


def test_it_has_the_control_loops_driver_api() -> None:
    from fleet.driving import Driver

    for name, member in inspect.getmembers(Driver, inspect.isfunction):
        if name.startswith("_"):
            continue
        ours = getattr(MavlinkDriver, name, None)
        assert ours is not None, f"MavlinkDriver lacks {name}"
        assert list(inspect.signature(ours).parameters) == list(
            inspect.signature(member).parameters
        ), name


def test_estimates_use_the_simulators_kinematics() -> None:
    from fleet.simulation.vehicle import SimVehicle

    driver = MavlinkDriver("udpout:127.0.0.1:9", spec=SPEC, depot=DEPOT)
    sim = SimVehicle(SPEC, DEPOT)
    assert driver.time_to_s(TARGET, 0.0) == pytest.approx(sim.time_to_s(TARGET, 0.0))
    assert driver.time_home_s(TARGET) == pytest.approx(sim.time_home_s(TARGET))
    assert driver.recharge(100.0, 60.0) == 160.0
    assert driver.position_at(0.0) == DEPOT and driver.phase_at(0.0) == "landed"
    low = Position(TARGET.lat, TARGET.lng, 2.0)
    assert driver.time_to_s(low, 0.0) == pytest.approx(sim.time_to_s(low, 0.0))


def test_at_speed_zero_every_flight_ends_at_once(
    make_sim: Callable[..., MavSim], make_driver: Callable[..., MavlinkDriver]
) -> None:
    sim = make_sim(speed=0.0)
    driver = make_driver(clock=time.monotonic)
    driver.fly_to(TARGET, driver.clock())
    wait_until(lambda: driver.has_arrived(TARGET, 1.0), timeout=5.0, what="the arrival")
    driver.return_to_depot(driver.clock())
    wait_until(lambda: driver.is_landed_at(driver.clock()), timeout=5.0, what="the landing")
    # The simulated clock moved by exactly the flights' durations.
    takeoff, out = 40 / 3, distance_m(DEPOT.with_alt(40), TARGET) / SPEC.max_speed_mps
    home = distance_m(TARGET, DEPOT.with_alt(40)) / SPEC.max_speed_mps + 40 / 3
    assert sim.sim_now() == pytest.approx(takeoff + out + home)
    assert sim.flight_s() == pytest.approx(takeoff + out + home)
    assert sim.battery_fraction() == pytest.approx(1 - sim.flight_s() / SPEC.battery_s)


@pytest.mark.parametrize("link_timeout_s", [2.0, 30.0], ids=["link-lost", "quick-reboot"])
def test_a_restarted_autopilot_is_set_up_again_and_commanded_only_on_fresh_state(
    make_sim: Callable[..., MavSim],
    make_driver: Callable[..., MavlinkDriver],
    link_timeout_s: float,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Issue 25: after the autopilot restarts (noticed by a lost link, or by its uptime
    going back), the worker asks for telemetry, home and the fence again before it commands."""
    first = make_sim(speed=SPEED)
    driver = make_driver(
        area=AREA, min_altitude_m=10.0, max_altitude_m=120.0, link_timeout_s=link_timeout_s
    )
    # Up a while, as a real autopilot is before it restarts.
    wait_until(lambda: (driver.uptime_s or 0) > 1.5, what="a second and a half of uptime")
    assert first.fence_polygons() == [[tuple(p) for p in AREA[:4]]]
    first.stop()
    if link_timeout_s < 10:
        wait_until(lambda: not driver.link_ok, what="the link lost")
    # A fresh autopilot on the same port: no fence, default rates, up for a moment only.
    again = make_sim(speed=SPEED)
    assert again.fence_polygons() == []
    wait_until(lambda: again.fence_polygons(), timeout=15, what="the fence uploaded again")
    assert again.fence_polygons() == [[tuple(p) for p in AREA[:4]]]
    assert again.message_interval_s(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT) == 1 / TELEMETRY_HZ
    wait_until(lambda: driver.link_ok, what="the link usable again")
    assert again.commands_seen(mavlink.MAV_CMD_COMPONENT_ARM_DISARM) == []
    assert "resynchronised" in caplog.text
    # And it flies as before (to a point inside its fence).
    clock = driver.clock
    inside = offset(DEPOT, north_m=-150, east_m=150, up_m=40)
    arrival = driver.fly_to(inside, clock())
    wait_until(lambda: driver.has_arrived(inside, 2.0, clock()), timeout=15, what="the target")
    assert clock() >= arrival - LATE_S
