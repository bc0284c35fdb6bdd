"""MavSim in GUIDED as ArduCopter flies it, driven by a plain pymavlink ground station: guided
waypoints (MISSION_ITEM(_INT) with current=2), MAV_CMD_DO_REPOSITION and position targets in
the global and the local frame, and the refusals a ground station sees."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator

import pytest

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import DEPOT, wait_until
from tests.fleet.mavlink.test_sim_with_a_plain_gcs import Gcs

SPEED = 40.0
GROUND_AMSL_M = 400.0


class Station(Gcs):
    """The plain ground station, with the few more messages these tests send."""

    def command_int(
        self, command: int, frame: int, *params: float, x: float = 0.0, y: float = 0.0,
        z: float = 0.0, component: int = 1,
    ) -> int:  # fmt: skip
        values = [*params, *[0.0] * (4 - len(params))]
        self.mav.command_int_send(
            1, component, frame, command, 0, 0, *values, round(x * 1e7), round(y * 1e7), z
        )
        return int(self.wait("COMMAND_ACK", lambda m: m.command == command).result)

    def guided_item(
        self, frame: int, target: Position, alt: float, *, as_float: bool = False
    ) -> int:
        """A guided waypoint (current=2); returns the MISSION_ACK's result."""
        if as_float:
            self.mav.mission_item_send(
                1, 1, 0, frame, mavlink.MAV_CMD_NAV_WAYPOINT, 2, 0,
                0, 0, 0, 0, target.lat, target.lng, alt,
            )  # fmt: skip
        else:
            self.mav.mission_item_int_send(
                1, 1, 0, frame, mavlink.MAV_CMD_NAV_WAYPOINT, 2, 0,
                0, 0, 0, 0, round(target.lat * 1e7), round(target.lng * 1e7), alt,
            )  # fmt: skip
        return int(self.wait("MISSION_ACK").type)

    def take_off(self, sim: MavSim, alt: float) -> None:
        """GUIDED, armed and hovering ``alt`` metres above home."""
        self.wait("HEARTBEAT")
        self.conn.set_mode("GUIDED")
        wait_until(lambda: sim.mode == "GUIDED", what="GUIDED")
        assert self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
        assert self.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt) == 0
        wait_until(lambda: abs(sim.position().alt - alt) < 0.05, what="the take-off")


def at(sim: MavSim, target: Position, within_m: float = 0.5) -> Callable[[], bool]:
    return lambda: distance_m(sim.position(), target) < within_m


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=SPEED, ground_amsl_m=GROUND_AMSL_M)


@pytest.fixture
def gcs(port: int, sim: MavSim) -> Iterator[Station]:
    station = Station(port)
    yield station
    station.close()


def test_guided_waypoints_in_the_relative_and_the_absolute_frame(sim: MavSim, gcs: Station) -> None:
    gcs.take_off(sim, 20)
    first = offset(DEPOT, north_m=120, east_m=-60, up_m=35)
    relative = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    # MAVProxy's "guided LAT LNG ALT": MISSION_ITEM_INT, current=2, answered by MISSION_ACK.
    assert gcs.guided_item(relative, first, 35) == mavlink.MAV_MISSION_ACCEPTED
    wait_until(at(sim, first), what="the first guided waypoint")

    # The older float MISSION_ITEM, its altitude above mean sea level (MAV_FRAME_GLOBAL).
    second = offset(DEPOT, north_m=-80, east_m=90, up_m=25)
    amsl = GROUND_AMSL_M + 25
    assert gcs.guided_item(mavlink.MAV_FRAME_GLOBAL, second, amsl, as_float=True) == 0
    # float32 degrees: about a metre of resolution.
    wait_until(at(sim, second, within_m=2.0), what="the second guided waypoint")
    assert sim.mode == "GUIDED" and sim.armed and not sim.on_ground


def test_guided_waypoints_are_refused_with_a_reason(sim: MavSim, gcs: Station) -> None:
    target = offset(DEPOT, north_m=50, east_m=50, up_m=20)
    gcs.wait("HEARTBEAT")
    gcs.conn.set_mode("GUIDED")
    wait_until(lambda: sim.mode == "GUIDED", what="GUIDED")
    relative = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    # On the ground: ArduCopter would keep it and fly it never; it is refused here.
    assert gcs.guided_item(relative, target, 20) == mavlink.MAV_MISSION_ERROR
    assert "Guided: not flying: arm and take off first" in sim.texts_sent()

    gcs.take_off(sim, 15)
    hover = sim.position()
    # A local frame is no frame for a guided waypoint.
    result = gcs.guided_item(mavlink.MAV_FRAME_LOCAL_NED, target, 20)
    assert result == mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    # Outside GUIDED (LOITER holds) the waypoint is an error, as ArduCopter answers.
    gcs.conn.set_mode("LOITER")
    wait_until(lambda: sim.mode == "LOITER", what="LOITER")
    assert gcs.guided_item(relative, target, 20) == mavlink.MAV_MISSION_ERROR
    assert distance_m(sim.position(), hover) < 0.5


def test_reposition_switches_to_guided_and_flies_there(sim: MavSim, gcs: Station) -> None:
    gcs.take_off(sim, 20)
    gcs.conn.set_mode("LOITER")
    wait_until(lambda: sim.mode == "LOITER", what="LOITER")
    target = offset(DEPOT, north_m=-150, east_m=40, up_m=30)
    reposition = mavlink.MAV_CMD_DO_REPOSITION
    relative = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT

    # Outside GUIDED without MAV_DO_REPOSITION_FLAGS_CHANGE_MODE: denied, it stays.
    denied = gcs.command_int(reposition, relative, -1, 0, x=target.lat, y=target.lng, z=30)
    assert denied == mavlink.MAV_RESULT_DENIED and sim.mode == "LOITER"

    # With the flag (what MAVSDK's goto_location sends), it switches to GUIDED and goes.
    change_mode = mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
    assert (
        gcs.command_int(reposition, relative, -1, change_mode, x=target.lat, y=target.lng, z=30)
        == 0
    )
    assert sim.mode == "GUIDED"
    wait_until(at(sim, target), what="the reposition target")

    # COMMAND_LONG: lat/lng in param5/6, the altitude relative to home.
    back = offset(DEPOT, north_m=20, east_m=-30, up_m=12)
    assert gcs.command(reposition, -1, 0, 0, math.nan, back.lat, back.lng, 12) == 0
    wait_until(at(sim, back, within_m=1.0), what="the second reposition target")

    # A local frame gets a refusal, not silence.
    local = gcs.command_int(reposition, mavlink.MAV_FRAME_LOCAL_NED, -1, 0, x=1, y=1, z=-10)
    assert local == mavlink.MAV_RESULT_DENIED


def test_position_targets_in_the_local_ned_frame(sim: MavSim, gcs: Station) -> None:
    gcs.take_off(sim, 10)
    position_only = 0b110111111000
    # MAV_FRAME_LOCAL_NED: metres north, east and down from home (ArduCopter's EKF origin).
    gcs.mav.set_position_target_local_ned_send(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, position_only, 100, -50, -30, 0, 0, 0, 0, 0, 0, 0, 0
    )
    target = offset(DEPOT, north_m=100, east_m=-50, up_m=30)
    wait_until(at(sim, target), what="the local target")

    # MAV_FRAME_LOCAL_OFFSET_NED: from where it is.
    gcs.mav.set_position_target_local_ned_send(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_OFFSET_NED, position_only,
        -20, 10, 5, 0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip
    moved = offset(target, north_m=-20, east_m=10, up_m=-5)
    wait_until(at(sim, moved), what="the offset target")

    # A body frame is not flown: said in a STATUSTEXT, and the vehicle holds where it is.
    gcs.mav.set_position_target_local_ned_send(
        0, 1, 1, mavlink.MAV_FRAME_BODY_NED, position_only, 50, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    text = gcs.wait("STATUSTEXT", lambda m: "frame" in m.text)
    assert text.text == "Guided: frame 8 not supported"
    assert distance_m(sim.position(), moved) < 0.5

    # The global target keeps working next to it.
    there = offset(DEPOT, north_m=10, east_m=10, up_m=15)
    gcs.mav.set_position_target_global_int_send(
        0, 1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, position_only,
        round(there.lat * 1e7), round(there.lng * 1e7), 15, 0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip
    wait_until(at(sim, there), what="the global target")


def test_a_silent_ground_station_sends_the_copter_home_by_its_gcs_failsafe(
    sim: MavSim, gcs: Station
) -> None:
    """ArduCopter's GCS failsafe (FS_GCS_ENABLE, FS_GCS_TIMEOUT): off as it ships; on, a
    ground station silent for the timeout sends the flying copter home, which lands there."""
    gcs.conn.param_set_send("FS_GCS_ENABLE", 1)
    gcs.conn.param_set_send("FS_GCS_TIMEOUT", 2.0)
    gcs.wait("PARAM_VALUE", lambda m: m.param_id == "FS_GCS_TIMEOUT")
    assert sim.param("FS_GCS_ENABLE") == 1
    gcs.take_off(sim, 30)
    target = offset(DEPOT, north_m=-300, east_m=150, up_m=30)
    assert gcs.guided_item(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, target, 30) == 0
    wait_until(lambda: distance_m(sim.position(), DEPOT) > 50, what="the copter away")
    # The ground station goes silent (its last heartbeat now), the copter flies on for the
    # timeout, then returns.
    gcs.wait("HEARTBEAT")
    silent = time.monotonic()
    wait_until(lambda: sim.mode == "RTL", timeout=8, what="RTL")
    assert time.monotonic() - silent > 1.0
    assert "GCS Failsafe" in sim.texts_sent()
    wait_until(lambda: sim.on_ground and not sim.armed, timeout=30, what="the landing")
    assert distance_m(sim.position(), DEPOT) < 1.0
    # Heard again: cleared (the copter stays where the failsafe left it).
    gcs.wait("STATUSTEXT", lambda m: m.text.startswith("GCS Failsafe Cleared"), timeout=5)
