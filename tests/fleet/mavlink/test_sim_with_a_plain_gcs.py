"""MavSim driven by a plain pymavlink ground station (mavutil directly, not our link or driver):
what any GCS sees of it over a real UDP link on loopback."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from fleet.geo import distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import DEPOT, SPEC


class Gcs:
    """A minimal ground station: mavutil, a heartbeat now and then, and waiting with a deadline."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=255, source_component=190
        )
        self.mav = self.conn.mav
        self.texts: list[Any] = []  # every STATUSTEXT received
        self._beat_at = 0.0

    def beat(self) -> None:
        if time.monotonic() >= self._beat_at:
            self.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self._beat_at = time.monotonic() + 0.5

    def wait(
        self, kind: str, condition: Callable[[Any], bool] = lambda m: True, timeout: float = 10.0
    ) -> Any:
        """The next message of a type that meets the condition (heartbeats go out meanwhile)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.beat()
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            if msg.get_type() == "STATUSTEXT":
                self.texts.append(msg)
            if msg.get_type() == kind and condition(msg):
                return msg
        raise AssertionError(f"no {kind} within {timeout:g} s")

    def command(self, command: int, *params: float) -> int:
        values = [*params, *[0.0] * (7 - len(params))]
        self.mav.command_long_send(1, 1, command, 0, *values)
        return int(self.wait("COMMAND_ACK", lambda m: m.command == command).result)

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=40.0)


@pytest.fixture
def gcs(port: int, sim: MavSim) -> Iterator[Gcs]:
    station = Gcs(port)
    yield station
    station.close()


def test_a_gcs_flies_it_from_take_off_to_landing(sim: MavSim, gcs: Gcs) -> None:
    beat = gcs.wait("HEARTBEAT")
    position = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, position, 50_000) == 0
    assert beat.type == mavlink.MAV_TYPE_QUADROTOR
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert beat.custom_mode == 0 and not beat.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED

    gcs.conn.set_mode("GUIDED")  # pymavlink's own mode mapping for ArduCopter
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 4)
    gcs.conn.arducopter_arm()
    gcs.wait("HEARTBEAT", lambda m: m.base_mode & armed)
    assert gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 20) == 0
    gcs.wait("GLOBAL_POSITION_INT", lambda m: m.relative_alt > 19_500)

    target = offset(DEPOT, north_m=-150, east_m=-80, up_m=40)
    gcs.mav.set_position_target_global_int_send(
        0, 1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b110111111000,
        round(target.lat * 1e7), round(target.lng * 1e7), target.alt,
        0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip
    there = gcs.wait(
        "GLOBAL_POSITION_INT",
        lambda m: distance_m(_position(m), target) < 0.5 and abs(m.vx) + abs(m.vy) < 5,
    )
    assert abs(there.relative_alt - 40_000) < 500

    gcs.conn.set_mode("RTL")
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 6)
    landed = gcs.wait("HEARTBEAT", lambda m: not m.base_mode & armed)  # disarms on the ground
    assert landed.custom_mode == 6
    home = gcs.wait("GLOBAL_POSITION_INT")
    assert distance_m(_position(home), DEPOT) < 0.5
    assert "Disarming motors" in sim.texts_sent()


def test_arming_is_refused_with_a_reason(sim: MavSim, gcs: Gcs) -> None:
    gcs.wait("HEARTBEAT")
    # STABILIZE allows arming, AUTO does not (and AUTO needs a mission anyway).
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 3) == mavlink.MAV_RESULT_FAILED
    gcs.conn.set_mode("RTL")
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 6)
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_DENIED
    assert "PreArm: Mode not armable" in sim.texts_sent()

    gcs.conn.set_mode("GUIDED")
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 4)
    sim.set_battery(0.1)
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_DENIED
    # ArduPilot says why before it answers, so the reason is already there.
    text = next(t for t in gcs.texts if "Battery" in t.text)
    assert text.text == "PreArm: Battery 1 below minimum arming capacity"
    assert text.severity == mavlink.MAV_SEVERITY_CRITICAL


def test_every_command_is_acknowledged(sim: MavSim, gcs: Gcs) -> None:
    gcs.wait("HEARTBEAT")
    assert gcs.command(mavlink.MAV_CMD_DO_SET_ROI_NONE) == mavlink.MAV_RESULT_UNSUPPORTED
    # Take-off needs GUIDED and armed motors.
    assert (
        gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 20) == mavlink.MAV_RESULT_FAILED
    )
    # COMMAND_INT is acknowledged the same way.
    gcs.mav.command_int_send(1, 1, 0, mavlink.MAV_CMD_DO_SET_ROI_NONE, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    ack = gcs.wait("COMMAND_ACK", lambda m: m.command == mavlink.MAV_CMD_DO_SET_ROI_NONE)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED and ack.target_system == 255


def test_message_rates_and_requests(sim: MavSim, gcs: Gcs) -> None:
    gcs.wait("HEARTBEAT")
    position = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    battery = mavlink.MAVLINK_MSG_ID_BATTERY_STATUS
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, position, 50_000) == 0
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, battery, 100_000) == 0
    assert sim.message_interval_s(position) == pytest.approx(0.05)
    first = gcs.wait("GLOBAL_POSITION_INT")
    for _ in range(10):
        last = gcs.wait("GLOBAL_POSITION_INT")
    # Ten more at 20 Hz: about half a second of boot time later.
    assert 0.3 < (last.time_boot_ms - first.time_boot_ms) / 1000 < 1.0
    status = gcs.wait("BATTERY_STATUS")
    assert status.battery_remaining == 100 and status.voltages[0] == 4200
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, battery, -1) == 0
    assert sim.message_interval_s(battery) is None

    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION) == 0
    home = gcs.wait("HOME_POSITION")
    assert (home.latitude, home.longitude) == (round(DEPOT.lat * 1e7), round(DEPOT.lng * 1e7))
    sys_status = gcs.wait("SYS_STATUS")
    assert sys_status.battery_remaining == 100 and sys_status.voltage_battery == 16800


def test_the_parameter_protocol(sim: MavSim, gcs: Gcs) -> None:
    gcs.wait("HEARTBEAT")
    gcs.mav.param_request_list_send(1, 1)
    names = set()
    while len(names) < 16:
        value = gcs.wait("PARAM_VALUE")
        names.add(value.param_id)
        assert value.param_count == 16
    assert {"FENCE_ENABLE", "FENCE_ALT_MAX", "FENCE_TYPE", "BATT_CAPACITY", "WPNAV_SPEED"} <= names

    gcs.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
    speed = gcs.wait("PARAM_VALUE", lambda m: m.param_id == "WPNAV_SPEED")
    assert speed.param_value == SPEC.max_speed_mps * 100  # cm/s
    assert speed.param_type == mavlink.MAV_PARAM_TYPE_REAL32

    gcs.conn.param_set_send("FENCE_ALT_MAX", 80.0)
    echo = gcs.wait("PARAM_VALUE", lambda m: m.param_id == "FENCE_ALT_MAX")
    assert echo.param_value == 80.0 and sim.param("FENCE_ALT_MAX") == 80.0
    gcs.mav.param_set_send(1, 1, b"FENCE_ENABLE", 1, mavlink.MAV_PARAM_TYPE_INT8)
    assert gcs.wait("PARAM_VALUE", lambda m: m.param_id == "FENCE_ENABLE").param_value == 1.0


def test_fence_items_go_in_and_come_back(sim: MavSim, gcs: Gcs) -> None:
    gcs.wait("HEARTBEAT")
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    vertices = [(48.109, 12.859), (48.109, 12.864), (48.114, 12.864)]
    gcs.mav.mission_count_send(1, 1, len(vertices), fence)
    for _ in vertices:
        request = gcs.wait("MISSION_REQUEST_INT", lambda m: m.mission_type == fence)
        lat, lng = vertices[request.seq]
        gcs.mav.mission_item_int_send(
            1, 1, request.seq, mavlink.MAV_FRAME_GLOBAL,
            mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, 0, 1,
            3, 0, 0, 0, round(lat * 1e7), round(lng * 1e7), 0, fence,
        )  # fmt: skip
    ack = gcs.wait("MISSION_ACK", lambda m: m.mission_type == fence)
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED
    assert sim.fence_polygons() == [vertices]

    gcs.mav.mission_request_list_send(1, 1, fence)
    assert gcs.wait("MISSION_COUNT", lambda m: m.mission_type == fence).count == 3
    gcs.mav.mission_request_int_send(1, 1, 2, fence)
    item = gcs.wait("MISSION_ITEM_INT", lambda m: m.mission_type == fence)
    assert (item.seq, item.x, item.y, item.param1) == (2, 481140000, 128640000, 3)

    # A waypoint is no fence item: the upload is refused and the fence stays.
    gcs.mav.mission_count_send(1, 1, 1, fence)
    gcs.wait("MISSION_REQUEST_INT", lambda m: m.mission_type == fence)
    gcs.mav.mission_item_int_send(
        1, 1, 0, 0, mavlink.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, 0, 0, 10, fence
    )
    refused = gcs.wait("MISSION_ACK", lambda m: m.mission_type == fence)
    assert refused.type == mavlink.MAV_MISSION_UNSUPPORTED
    assert sim.fence_polygons() == [vertices]


def _position(msg: Any) -> Any:
    from fleet.geo import Position

    return Position(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000)
