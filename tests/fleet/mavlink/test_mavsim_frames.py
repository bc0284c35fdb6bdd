"""MavSim as a rover, a boat and a submarine (ArduRover and ArduSub towards a ground station),
and MavlinkDriver flying each: heartbeat types and mode numbers, no take-off, GUIDED in the
plane or below the surface, HOLD, RTL and SURFACE, and a configured kind the vehicle is not."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.driver import MavlinkDriver
from fleet.mavlink.errors import UnsupportedVehicle
from fleet.mavlink.exchange import Heartbeat
from fleet.mavlink.modes import (
    ARDUROVER_MODES,
    ARDUSUB_MODES,
    Autopilot,
    custom_mode_of,
    mode_name,
)
from fleet.mavlink.wire import mavlink
from fleet.simulation.vehicle import PHASE_LANDED, VehicleSpec
from tests.fleet.mavlink.conftest import AREA, DEPOT, sim_clock, wait_until
from tests.fleet.mavlink.test_mavsim_with_mavproxy import MavProxy
from tests.fleet.mavlink.test_sim_with_a_plain_gcs import Gcs

SPEED = 40.0
ROVER = VehicleSpec(max_speed_mps=5.0, climb_rate_mps=1.0, kind="ground", turn_rate_dps=90.0)
SUB = VehicleSpec(max_speed_mps=2.0, climb_rate_mps=0.5, dive_rate_mps=1.0, kind="underwater")
ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
POSITION_ONLY = 0b110111111000
RELATIVE = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


@pytest.fixture
def gcs(port: int) -> Iterator[Gcs]:
    station = Gcs(port)
    yield station
    station.close()


def send_target(gcs: Gcs, target: Position, alt: float) -> None:
    gcs.mav.set_position_target_global_int_send(
        0, 1, 1, RELATIVE, POSITION_ONLY, round(target.lat * 1e7), round(target.lng * 1e7), alt,
        0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip


def arm_in_guided(gcs: Gcs, sim: MavSim) -> None:
    """GUIDED (pymavlink picks the number from the heartbeat's type) and armed; positions at
    20 Hz."""
    gcs.wait("HEARTBEAT")
    position = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, position, 50_000) == 0
    gcs.conn.set_mode("GUIDED")
    wait_until(lambda: sim.mode == "GUIDED", what="GUIDED")
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    gcs.wait("HEARTBEAT", lambda m: m.base_mode & ARMED)


@pytest.mark.parametrize(
    ("frame", "mav_type", "kind"),
    [
        ("copter", mavlink.MAV_TYPE_QUADROTOR, "aerial"),
        ("rover", mavlink.MAV_TYPE_GROUND_ROVER, "ground"),
        ("boat", mavlink.MAV_TYPE_SURFACE_BOAT, "surface"),
        ("sub", mavlink.MAV_TYPE_SUBMARINE, "underwater"),
    ],
)
def test_each_frame_says_what_it_is_and_its_modes_as_pymavlink_reads_them(
    make_sim: Callable[..., MavSim], gcs: Gcs, frame: str, mav_type: int, kind: str
) -> None:
    sim = make_sim(frame=frame)
    beat = gcs.wait("HEARTBEAT")
    assert (beat.type, beat.autopilot) == (mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert mavutil.mode_string_v10(beat) == ("STABILIZE" if frame == "copter" else "MANUAL")
    gcs.conn.set_mode("GUIDED")
    beat = gcs.wait("HEARTBEAT", lambda m: mavutil.mode_string_v10(m) == "GUIDED")
    assert beat.custom_mode == {"copter": 4, "rover": 15, "boat": 15, "sub": 4}[frame]
    assert sim.mode == "GUIDED"


def test_the_mode_tables_are_ardurovers_and_ardusubs() -> None:
    for number, name in mavutil.mode_mapping_rover.items():
        if name != "LEARNING":  # Rover's mode 2, removed from the firmware
            assert ARDUROVER_MODES[name] == number
    for number, name in mavutil.mode_mapping_sub.items():
        assert ARDUSUB_MODES[name] == number
    assert (ARDUSUB_MODES["MOTOR_DETECT"], ARDUSUB_MODES["SURFTRAK"]) == (20, 21)
    rover, sub = mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_TYPE_SUBMARINE
    assert mode_name(Autopilot.ARDUPILOT, 15, rover) == "GUIDED"
    assert mode_name(Autopilot.ARDUPILOT, 4, rover) == "HOLD"
    assert mode_name(Autopilot.ARDUPILOT, 4, sub) == "GUIDED"
    assert mode_name(Autopilot.ARDUPILOT, 9, sub) == "SURFACE"
    assert mode_name(Autopilot.ARDUPILOT, 4) == "GUIDED"  # a copter's, as before
    assert custom_mode_of(Autopilot.ARDUPILOT, "RTL", mavlink.MAV_TYPE_SURFACE_BOAT) == 11
    with pytest.raises(KeyError):
        custom_mode_of(Autopilot.ARDUPILOT, "RTL", sub)  # ArduSub has no RTL
    beat = Heartbeat(1, 1, rover, Autopilot.ARDUPILOT, 0, 11, 0, 0.0)
    assert beat.mode == "RTL"


def test_a_rover_refuses_to_take_off_and_drives_in_guided_at_altitude_0(
    make_sim: Callable[..., MavSim], gcs: Gcs
) -> None:
    sim = make_sim(spec=ROVER, frame="rover", speed=SPEED)
    arm_in_guided(gcs, sim)
    assert gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10) == UNSUPPORTED
    assert gcs.command(mavlink.MAV_CMD_NAV_LAND) == UNSUPPORTED

    # A target with an altitude: ArduRover drives to it in the plane.
    target = offset(DEPOT, north_m=-60, east_m=80)
    send_target(gcs, target, 15.0)
    heights = []
    while distance_m(sim.position(), target) > 0.5:
        msg = gcs.wait("GLOBAL_POSITION_INT")
        heights.append(msg.relative_alt)
    assert set(heights) == {0}
    assert sim.position().alt == 0.0 and sim.armed and sim.mode == "GUIDED"

    # HOLD stops it half-way to the next target.
    far = offset(DEPOT, north_m=400, east_m=0)
    send_target(gcs, far, 0.0)
    wait_until(lambda: distance_m(sim.position(), target) > 30, what="driving on")
    gcs.conn.set_mode("HOLD")
    wait_until(lambda: sim.mode == "HOLD", what="HOLD")
    stopped = sim.position()
    assert distance_m(stopped, far) > 100
    gcs.wait("GLOBAL_POSITION_INT", lambda m: m.vx == 0 and m.vy == 0)
    assert distance_m(sim.position(), stopped) < 0.5 and sim.armed


def test_a_rover_drives_home_in_rtl_and_stops_there_armed(
    make_sim: Callable[..., MavSim], gcs: Gcs
) -> None:
    sim = make_sim(spec=ROVER, frame="rover", speed=SPEED)
    arm_in_guided(gcs, sim)
    away = offset(DEPOT, north_m=120, east_m=-40)
    send_target(gcs, away, 0.0)
    wait_until(lambda: distance_m(sim.position(), away) < 0.5, what="the target")

    assert gcs.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == 0
    wait_until(lambda: sim.mode == "RTL" and sim.on_ground, what="parked at home")
    assert distance_m(sim.position(), DEPOT) < 0.01
    assert sim.armed  # ArduRover does not disarm by itself
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0) == 0
    wait_until(lambda: not sim.armed, what="disarmed")


def test_a_sub_dives_to_5_m_in_guided_and_surface_brings_it_up(
    make_sim: Callable[..., MavSim], gcs: Gcs
) -> None:
    sim = make_sim(spec=SUB, frame="sub", speed=SPEED)
    hud = mavlink.MAVLINK_MSG_ID_VFR_HUD
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, hud, 100_000) == 0
    arm_in_guided(gcs, sim)
    assert gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10) == UNSUPPORTED
    assert gcs.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == UNSUPPORTED

    target = offset(DEPOT, north_m=20, east_m=10)
    send_target(gcs, target, -5.0)
    gcs.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt == -5000, timeout=15)
    assert distance_m(sim.position(), target.with_alt(-5.0)) < 0.01
    assert gcs.wait("VFR_HUD").alt == pytest.approx(-5.0)  # ArduSub's HUD shows the depth

    gcs.conn.set_mode("SURFACE")
    wait_until(lambda: sim.mode == "SURFACE", what="SURFACE")
    gcs.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt == 0, timeout=15)
    assert distance_m(sim.position(), target.with_alt(0.0)) < 0.01  # straight up
    assert sim.armed


def test_a_rovers_gcs_failsafe_holds_it_where_it_is(
    make_sim: Callable[..., MavSim], gcs: Gcs
) -> None:
    sim = make_sim(spec=ROVER, frame="rover", speed=4.0)
    arm_in_guided(gcs, sim)
    gcs.conn.param_set_send("FS_GCS_ENABLE", 1)
    gcs.wait("PARAM_VALUE", lambda m: m.param_id == "FS_GCS_ENABLE" and m.param_value == 1)
    send_target(gcs, offset(DEPOT, north_m=800, east_m=0), 0.0)
    wait_until(lambda: sim.position().lat > DEPOT.lat, what="driving")
    # The ground station goes silent: after FS_TIMEOUT, FS_ACTION (HOLD, as ArduRover ships).
    wait_until(lambda: sim.mode == "HOLD", timeout=10, what="the failsafe's HOLD")
    assert "GCS Failsafe" in sim.texts_sent() and sim.armed


# --- MavlinkDriver ----------------------------------------------------------------------------


def driver_for(port: int, spec: VehicleSpec, **options: object) -> MavlinkDriver:
    return MavlinkDriver(
        f"udpout:127.0.0.1:{port}",
        spec=spec,
        depot=DEPOT,
        clock=sim_clock(SPEED),
        name="test",
        **options,  # type: ignore[arg-type]
    )


def test_the_driver_drives_a_rover_out_and_home_where_it_parks(
    make_sim: Callable[..., MavSim], port: int
) -> None:
    sim = make_sim(spec=ROVER, frame="rover", speed=SPEED)
    driver = driver_for(
        port, ROVER, kind="ground", area=AREA, min_altitude_m=0.0, max_altitude_m=0.0
    )
    driver.connect(timeout_s=5)
    try:
        assert driver.kind == "ground" and driver.is_landed_at(0)
        assert sim.param("FENCE_ENABLE") == 1 and sim.param("FENCE_TYPE") == 4  # polygons only
        task = offset(DEPOT, north_m=-150, east_m=60)
        driver.fly_to(task, 0.0)
        wait_until(lambda: driver.has_arrived(task, 1.0), what="the task")
        assert sim.position().alt == 0.0 and sim.mode == "GUIDED"
        assert sim.commands_seen(mavlink.MAV_CMD_NAV_TAKEOFF) == []

        driver.return_to_depot(0.0)
        wait_until(lambda: driver.phase_at(0) == PHASE_LANDED, what="parked at home")
        assert not sim.armed and distance_m(sim.position(), DEPOT) < 0.5

        # "Land now" on the way out: HOLD where it is, then parked (disarmed) there.
        far = offset(DEPOT, north_m=-300, east_m=0)
        driver.fly_to(far, 0.0)
        wait_until(lambda: distance_m(sim.position(), DEPOT) > 40, what="driving out")
        driver.land(0.0)
        wait_until(lambda: driver.is_landed_at(0), what="stopped")
        assert sim.mode == "HOLD" and not sim.armed
        assert distance_m(sim.position(), far) > 50
    finally:
        driver.close()


def test_the_driver_dives_a_sub_and_brings_it_home_at_the_surface(
    make_sim: Callable[..., MavSim], port: int
) -> None:
    sim = make_sim(spec=SUB, frame="sub", speed=SPEED)
    driver = driver_for(port, SUB, kind="underwater")
    driver.connect(timeout_s=5)
    try:
        task = offset(DEPOT, north_m=40, east_m=-30, up_m=-5)
        driver.fly_to(task, 0.0)
        wait_until(lambda: driver.has_arrived(task, 0.5), what="the task at 5 m depth")
        assert sim.position().alt == pytest.approx(-5.0)

        driver.return_to_depot(0.0)
        wait_until(lambda: driver.is_landed_at(0), what="home at the surface")
        assert not sim.armed and sim.mode == "GUIDED"
        assert distance_m(sim.position(), DEPOT) < 1.0

        driver.fly_to(task, 0.0)
        wait_until(lambda: sim.position().alt < -4.9, what="down again")
        driver.land(0.0)  # SURFACE where it is
        wait_until(lambda: driver.is_landed_at(0), what="surfaced")
        assert sim.mode == "SURFACE" and sim.position().alt == 0.0
    finally:
        driver.close()


def test_the_driver_refuses_a_vehicle_of_another_kind_than_configured(
    make_sim: Callable[..., MavSim], port: int
) -> None:
    make_sim(spec=SUB, frame="sub")
    driver = driver_for(port, ROVER, kind="ground")
    with pytest.raises(UnsupportedVehicle) as refused:
        driver.connect(timeout_s=5)
    assert "configured as a ground vehicle, but the autopilot reports a submarine" in str(
        refused.value
    )
    assert refused.value.permanent


# --- a real ground station ----------------------------------------------------------------------


@pytest.mark.slow
def test_mavproxy_drives_a_rover_with_ardurovers_modes(
    make_sim: Callable[..., MavSim], port: int, tmp_path: Path
) -> None:
    sim = make_sim(spec=ROVER, frame="rover", speed=SPEED)
    mavproxy = MavProxy(port, tmp_path)
    try:
        mavproxy.eventually(lambda: sim.gcs_heartbeats > 0, "heartbeat from MAVProxy", timeout=60)
        mavproxy.eventually(lambda: "MANUAL" in mavproxy.output(), "ArduRover's MANUAL shown")
        mavproxy.type("mode guided")
        mavproxy.eventually(lambda: sim.mode == "GUIDED", "GUIDED")
        mavproxy.type("arm throttle")
        mavproxy.eventually(lambda: sim.armed, "arming")
        spot = offset(DEPOT, north_m=70, east_m=50)
        mavproxy.type(f"guided {spot.lat:.7f} {spot.lng:.7f} 0")
        mavproxy.eventually(lambda: distance_m(sim.position(), spot) < 0.5, "the guided point")
        mavproxy.type("mode hold")
        mavproxy.eventually(lambda: "HOLD" in mavproxy.output(), "HOLD shown")
        mavproxy.type("rtl")
        mavproxy.eventually(
            lambda: sim.on_ground and distance_m(sim.position(), DEPOT) < 0.01, "home"
        )
        assert sim.mode == "RTL"
    finally:
        mavproxy.close()
