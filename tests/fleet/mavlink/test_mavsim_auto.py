"""MavSim in AUTO as ArduCopter flies a mission, driven by a plain pymavlink ground station:
upload, MAV_CMD_MISSION_START, MISSION_CURRENT and MISSION_ITEM_REACHED item by item, jumps
(MAV_CMD_DO_SET_MISSION_CURRENT, MISSION_SET_CURRENT) and the refusals."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import DEPOT, wait_until
from tests.fleet.mavlink.test_mavsim_guided import Station

SPEED = 40.0
RELATIVE = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
A = offset(DEPOT, north_m=150, east_m=-100, up_m=30)
B = offset(DEPOT, north_m=-120, east_m=80, up_m=25)
HOLD_S = 20.0  # half a second of the test at SPEED: long enough to see it there


def item(command: int, where: Position | None = None, alt: float = 0.0, p1: float = 0.0) -> tuple:
    lat, lng = (where.lat, where.lng) if where is not None else (0.0, 0.0)
    return (command, lat, lng, alt, p1)


def upload(gcs: Station, items: list[tuple]) -> None:
    """The mission protocol: item 0 is home, as ArduPilot keeps it."""
    full = [item(mavlink.MAV_CMD_NAV_WAYPOINT, DEPOT), *items]
    gcs.mav.mission_count_send(1, 1, len(full), mavlink.MAV_MISSION_TYPE_MISSION)
    for _ in full:
        request = gcs.wait("MISSION_REQUEST_INT")
        command, lat, lng, alt, p1 = full[request.seq]
        gcs.mav.mission_item_int_send(
            1, 1, request.seq, RELATIVE, command, 0, 1, p1, 0, 0, 0,
            round(lat * 1e7), round(lng * 1e7), alt, mavlink.MAV_MISSION_TYPE_MISSION,
        )  # fmt: skip
    assert gcs.wait("MISSION_ACK").type == mavlink.MAV_MISSION_ACCEPTED


def arm_in_guided(gcs: Station, sim: MavSim) -> None:
    gcs.wait("HEARTBEAT")
    gcs.conn.set_mode("GUIDED")
    wait_until(lambda: sim.mode == "GUIDED", what="GUIDED")
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=SPEED)


@pytest.fixture
def gcs(port: int, sim: MavSim) -> Iterator[Station]:
    station = Station(port)
    yield station
    station.close()


def test_a_mission_from_take_off_to_landing(sim: MavSim, gcs: Station) -> None:
    gcs.wait("HEARTBEAT")
    upload(
        gcs,
        [
            item(mavlink.MAV_CMD_NAV_TAKEOFF, alt=20),
            item(mavlink.MAV_CMD_NAV_WAYPOINT, A, 30, p1=HOLD_S),
            item(mavlink.MAV_CMD_DO_CHANGE_SPEED, p1=1),  # not flown: passed over
            item(mavlink.MAV_CMD_NAV_LOITER_TIME, B, 25, p1=20),  # 20 s (half a wall second)
            item(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH),
        ],
    )
    arm_in_guided(gcs, sim)
    assert gcs.command(mavlink.MAV_CMD_MISSION_START) == mavlink.MAV_RESULT_ACCEPTED
    assert sim.mode == "AUTO"

    first = gcs.wait("MISSION_CURRENT", lambda m: m.seq == 1)
    assert first.total == 6 and first.mission_state == mavlink.MISSION_STATE_ACTIVE
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 1)
    assert abs(sim.position().alt - 20) < 0.5
    wait_until(lambda: distance_m(sim.position(), A) < 0.5, what="the first waypoint")
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 2)  # after its hold time
    gcs.wait("MISSION_CURRENT", lambda m: m.seq == 4)
    wait_until(lambda: distance_m(sim.position(), B) < 0.5, what="the loiter point")
    arrived_s = sim.sim_now()
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 4)
    assert sim.sim_now() - arrived_s >= 19.0  # it waited there
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 5)
    assert sim.on_ground and not sim.armed and sim.mode == "AUTO"
    assert distance_m(sim.position(), DEPOT) < 0.5
    done = gcs.wait("MISSION_CURRENT", lambda m: m.mission_state == mavlink.MISSION_STATE_COMPLETE)
    assert done.seq == 5
    texts = sim.texts_sent()
    assert "Reached command #2" in texts
    assert [t for t in texts if t.startswith("Mission: ")] == [
        "Mission: 1 Takeoff",
        "Mission: 2 WP",
        "Mission: 4 LoitTime",
        "Mission: 5 RTL",
    ]


def test_auto_from_the_air_and_jumps(sim: MavSim, gcs: Station) -> None:
    gcs.take_off(sim, 15)
    upload(
        gcs,
        [
            item(mavlink.MAV_CMD_NAV_TAKEOFF, alt=10),  # already higher: done at once
            item(mavlink.MAV_CMD_NAV_WAYPOINT, offset(DEPOT, north_m=2000, east_m=0), 40),
            item(mavlink.MAV_CMD_NAV_WAYPOINT, B, 25, p1=HOLD_S),
            item(mavlink.MAV_CMD_NAV_LAND, A),
        ],
    )
    gcs.conn.set_mode("AUTO")
    wait_until(lambda: sim.mode == "AUTO", what="AUTO")
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 1)
    gcs.wait("MISSION_CURRENT", lambda m: m.seq == 2)

    # Half-way to a far waypoint, jump to the next one.
    jump = mavlink.MAV_CMD_DO_SET_MISSION_CURRENT
    assert gcs.command(jump, 9) == mavlink.MAV_RESULT_DENIED  # no item 9
    assert gcs.command(jump, 3) == mavlink.MAV_RESULT_ACCEPTED
    gcs.wait("MISSION_CURRENT", lambda m: m.seq == 3)
    wait_until(lambda: distance_m(sim.position(), B) < 0.5, what="the waypoint jumped to")
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 3)
    assert "Reached command #3" in sim.texts_sent()
    # NAV_LAND at a place: there, down, disarmed.
    gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 4)
    assert sim.on_ground and not sim.armed
    assert distance_m(sim.position(), A.with_alt(0)) < 0.5

    # The older MISSION_SET_CURRENT is answered with MISSION_CURRENT.
    gcs.mav.mission_set_current_send(1, 1, 2)
    assert gcs.wait("MISSION_CURRENT", lambda m: m.seq == 2).mission_state in (
        mavlink.MISSION_STATE_NOT_STARTED,
        mavlink.MISSION_STATE_ACTIVE,
    )
    assert sim.mission_current() == 2


def test_auto_is_refused_without_a_mission_or_a_take_off(sim: MavSim, gcs: Station) -> None:
    gcs.wait("HEARTBEAT")
    auto = (mavlink.MAV_CMD_DO_SET_MODE, 1, 3)
    assert gcs.command(*auto) == mavlink.MAV_RESULT_FAILED
    assert "Mode change to AUTO failed: no mission" in sim.texts_sent()
    assert gcs.command(mavlink.MAV_CMD_MISSION_START) == mavlink.MAV_RESULT_FAILED

    upload(gcs, [item(mavlink.MAV_CMD_NAV_WAYPOINT, A, 30)])
    arm_in_guided(gcs, sim)
    # Armed on the ground, a mission must begin with a take-off (ArduCopter's check).
    assert gcs.command(*auto) == mavlink.MAV_RESULT_FAILED
    assert sim.texts_sent()[-1] == "Mode change to AUTO failed: Auto: Missing Takeoff Cmd"
    assert sim.mode == "GUIDED" and sim.on_ground


def test_at_speed_zero_a_mission_ends_at_once(make_sim: Callable[..., MavSim], port: int) -> None:
    sim = make_sim(speed=0.0)
    gcs = Station(port)
    try:
        gcs.wait("HEARTBEAT")
        upload(
            gcs,
            [
                item(mavlink.MAV_CMD_NAV_TAKEOFF, alt=20),
                item(mavlink.MAV_CMD_NAV_WAYPOINT, A, 30, p1=HOLD_S),
                item(mavlink.MAV_CMD_NAV_DELAY, p1=HOLD_S),  # MAVSDK's loiter_time_s
                item(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH),
            ],
        )
        arm_in_guided(gcs, sim)
        assert gcs.command(mavlink.MAV_CMD_MISSION_START) == 0
        gcs.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 4)
        assert sim.on_ground and not sim.armed
        assert distance_m(sim.position(), DEPOT) < 0.5
        # The simulated clock moved through every leg, the hold and the delay.
        assert sim.sim_now() > 2 * HOLD_S + 2 * distance_m(DEPOT, A) / 10.0
        assert "Mission: 3 Delay" in sim.texts_sent()
    finally:
        gcs.close()
