"""The protocol pieces that need no link: connection strings, modes, parameter encoding, fence
items."""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from fleet.mavlink import LinkError, fence_polygon_items, inclusion_polygons, parse_endpoint
from fleet.mavlink.endpoint import DEFAULT_BAUD, mirror_endpoint
from fleet.mavlink.errors import CommandDenied, PreArmFailed
from fleet.mavlink.mission import MissionItem, validate_fence
from fleet.mavlink.modes import (
    ARDUCOPTER_MODES,
    PX4_MODES,
    Autopilot,
    custom_mode_of,
    mode_name,
    px4_custom_mode,
    px4_split,
    same_mode,
    set_mode_params,
)
from fleet.mavlink.params import decode, encode
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import AREA


@pytest.mark.parametrize(
    ("text", "scheme", "host", "port", "device", "baud"),
    [
        ("udpin:0.0.0.0:14550", "udpin", "0.0.0.0", 14550, "", DEFAULT_BAUD),
        ("udp:127.0.0.1:14550", "udpin", "127.0.0.1", 14550, "", DEFAULT_BAUD),
        ("udpout:10.0.0.2:14555", "udpout", "10.0.0.2", 14555, "", DEFAULT_BAUD),
        ("tcp:127.0.0.1:5760", "tcp", "127.0.0.1", 5760, "", DEFAULT_BAUD),
        ("tcpin:0.0.0.0:5760", "tcpin", "0.0.0.0", 5760, "", DEFAULT_BAUD),
        ("serial:/dev/ttyUSB0:921600", "serial", "", 0, "/dev/ttyUSB0", 921600),
        ("serial:/dev/ttyUSB0", "serial", "", 0, "/dev/ttyUSB0", DEFAULT_BAUD),
        ("/dev/ttyACM0,57600", "serial", "", 0, "/dev/ttyACM0", 57600),
        ("/dev/serial/by-id/usb-Hex_ProfiCNC_CubeOrange-if00", "serial", "", 0,
         "/dev/serial/by-id/usb-Hex_ProfiCNC_CubeOrange-if00", DEFAULT_BAUD),
        ("COM3,115200", "serial", "", 0, "COM3", 115200),
    ],
)  # fmt: skip
def test_connection_strings(
    text: str, scheme: str, host: str, port: int, device: str, baud: int
) -> None:
    endpoint = parse_endpoint(text)
    assert (endpoint.scheme, endpoint.host, endpoint.port) == (scheme, host, port)
    assert (endpoint.device, endpoint.baud) == (device, baud)


def test_the_pymavlink_device_of_an_endpoint() -> None:
    assert parse_endpoint("udp:127.0.0.1:14550").pymavlink_device == "udpin:127.0.0.1:14550"
    assert parse_endpoint("/dev/ttyACM0,57600").pymavlink_device == "/dev/ttyACM0"


@pytest.mark.parametrize(
    ("text", "complaint"),
    [
        ("", "empty"),
        ("http://vehicle", "unknown MAVLink connection"),
        ("udpin:14550", "HOST:PORT"),
        ("udpout:127.0.0.1:port", "port must be a number"),
        ("tcp:127.0.0.1:70000", "port must be a number"),
        ("serial::57600", "no serial device"),
    ],
)
def test_bad_connection_strings_are_permanent_errors(text: str, complaint: str) -> None:
    with pytest.raises(LinkError, match=complaint) as caught:
        parse_endpoint(text)
    assert caught.value.permanent


def test_the_simulator_listens_where_the_driver_sends() -> None:
    assert mirror_endpoint("udpout:127.0.0.1:14560") == "udpin:127.0.0.1:14560"
    assert mirror_endpoint("tcp:127.0.0.1:5760") == "tcpin:127.0.0.1:5760"
    with pytest.raises(LinkError):
        mirror_endpoint("/dev/ttyACM0,57600")


def test_arducopter_mode_numbers_agree_with_pymavlink() -> None:
    for name, number in ARDUCOPTER_MODES.items():
        assert mavutil.mode_mapping_acm[number] == name
    assert [ARDUCOPTER_MODES[m] for m in ("STABILIZE", "AUTO", "GUIDED", "LOITER", "RTL", "LAND")] == [
        0, 3, 4, 5, 6, 9,
    ]  # fmt: skip
    assert mode_name(Autopilot.ARDUPILOT, 4) == "GUIDED"
    assert mode_name(Autopilot.ARDUPILOT, 99) == "MODE(99)"
    assert set_mode_params(Autopilot.ARDUPILOT, "RTL") == (
        float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED),
        6.0,
        0.0,
    )


def test_px4_modes_put_main_and_sub_mode_in_the_upper_bytes() -> None:
    assert px4_custom_mode(6) == 0x00060000  # OFFBOARD
    assert px4_custom_mode(4, 5) == 0x05040000  # AUTO.RTL
    assert px4_split(0x03040000) == (4, 3)
    for name, (main, sub) in PX4_MODES.items():
        custom = custom_mode_of(Autopilot.PX4, name)
        assert mode_name(Autopilot.PX4, custom) == name
        assert set_mode_params(Autopilot.PX4, name)[1:] == (float(main), float(sub))
    # pymavlink decodes PX4 heartbeats the same way (its names drop the "AUTO.").
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    for ours, theirs in [
        ("OFFBOARD", "OFFBOARD"),
        ("POSCTL", "POSCTL"),
        ("AUTO.TAKEOFF", "TAKEOFF"),
        ("AUTO.LOITER", "LOITER"),
        ("AUTO.RTL", "RTL"),
        ("AUTO.LAND", "LAND"),
    ]:
        assert mavutil.interpret_px4_mode(base, custom_mode_of(Autopilot.PX4, ours)) == theirs
    # POSCTL may be reported with a sub-mode PX4 does not name; AUTO's sub-mode always counts.
    assert same_mode(Autopilot.PX4, px4_custom_mode(3, 2), px4_custom_mode(3))
    assert not same_mode(Autopilot.PX4, px4_custom_mode(4, 3), px4_custom_mode(4, 5))


def test_px4_integers_travel_bytewise_ardupilot_integers_as_floats() -> None:
    int32 = mavlink.MAV_PARAM_TYPE_INT32
    int8 = mavlink.MAV_PARAM_TYPE_INT8
    wire = encode(3, int32, bytewise=True)
    assert wire != 3.0 and decode(wire, int32, bytewise=True) == 3.0
    assert encode(3, int32, bytewise=False) == 3.0
    assert decode(encode(-2, int8, bytewise=True), int8, bytewise=True) == -2.0
    assert encode(2.5, mavlink.MAV_PARAM_TYPE_REAL32, bytewise=True) == 2.5
    with pytest.raises(ValueError, match="does not fit"):
        encode(300, int8, bytewise=False)


def test_an_area_becomes_one_inclusion_polygon_without_its_closing_point() -> None:
    items = fence_polygon_items(AREA)
    assert len(items) == 4
    assert {i.command for i in items} == {mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION}
    assert [i.param1 for i in items] == [4.0] * 4
    assert [i.seq for i in items] == [0, 1, 2, 3]
    assert (items[0].x, items[0].y) == (481090000, 128590000)
    assert inclusion_polygons(items) == [[tuple(p) for p in AREA[:4]]]
    assert validate_fence(items) == mavlink.MAV_MISSION_ACCEPTED


def test_bad_fences() -> None:
    with pytest.raises(ValueError, match="3 distinct"):
        fence_polygon_items([[48.1, 12.8], [48.2, 12.8], [48.1, 12.8]])
    with pytest.raises(ValueError, match="latitude"):
        fence_polygon_items([[91, 0], [0, 1], [1, 1]])
    items = fence_polygon_items(AREA)
    assert validate_fence(items[:3]) == mavlink.MAV_MISSION_INVALID_PARAM1  # cut short
    waypoint = MissionItem(command=mavlink.MAV_CMD_NAV_WAYPOINT)
    assert validate_fence([*items, waypoint]) == mavlink.MAV_MISSION_UNSUPPORTED


def test_which_refusals_are_permanent() -> None:
    takeoff = mavlink.MAV_CMD_NAV_TAKEOFF
    assert not CommandDenied(takeoff, mavlink.MAV_RESULT_TEMPORARILY_REJECTED).permanent
    for result in ("DENIED", "UNSUPPORTED", "FAILED"):
        denied = CommandDenied(takeoff, getattr(mavlink, f"MAV_RESULT_{result}"))
        assert denied.permanent
        assert str(denied) == f"MAV_CMD_NAV_TAKEOFF answered {result}"
    prearm = PreArmFailed(mavlink.MAV_RESULT_DENIED, ["PreArm: Battery 1 below minimum"])
    assert isinstance(prearm, CommandDenied) and not prearm.permanent
    assert "PreArm: Battery 1 below minimum" in str(prearm)
