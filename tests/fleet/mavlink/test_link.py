"""MavlinkLink against MavSim over loopback: commands, parameters, missions, link loss."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest
from pymavlink import mavutil

from fleet.mavlink import (
    CommandDenied,
    CommandTimeout,
    LinkError,
    LinkLost,
    MavlinkLink,
    MavSim,
    MissionRejected,
    ParamTimeout,
    fence_polygon_items,
)
from fleet.mavlink.mission import MissionItem
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import AREA, free_tcp_port, free_udp_port, wait_until

FENCE = mavlink.MAV_MISSION_TYPE_FENCE


@pytest.fixture
def open_link(port: int) -> Iterator[Callable[[], MavlinkLink]]:
    """Open a link to the test's MavSim (after starting it: a UDP heartbeat sent to a port
    nobody listens on yet is lost, and the next comes a second later)."""
    links: list[MavlinkLink] = []

    def open_() -> MavlinkLink:
        links.append(MavlinkLink(f"udpout:127.0.0.1:{port}", command_timeout_s=0.3).open())
        return links[-1]

    yield open_
    for link in links:
        link.close()


def test_the_link_finds_the_vehicle_by_its_heartbeat(
    make_sim: Callable[..., MavSim], open_link: Callable[[], MavlinkLink]
) -> None:
    sim = make_sim()
    link = open_link()
    beat = link.wait_heartbeat(5)
    assert (beat.system_id, beat.component_id) == (1, 1)
    assert beat.autopilot is Autopilot.ARDUPILOT and beat.mode == "STABILIZE"
    assert not beat.armed and link.link_ok
    # Our own heartbeats reach the vehicle (1 Hz), which is also how UDP learns our address.
    wait_until(lambda: sim.gcs_heartbeats >= 1, what="our heartbeat at the vehicle")


def test_no_vehicle_no_heartbeat(open_link: Callable[[], MavlinkLink]) -> None:
    link = open_link()
    with pytest.raises(LinkLost, match="no heartbeat") as caught:
        link.wait_heartbeat(0.3)
    assert not caught.value.permanent
    with pytest.raises(LinkLost):
        link.command_long(mavlink.MAV_CMD_DO_SET_ROI_NONE)


def test_commands_are_acknowledged_refused_or_timed_out(
    make_sim: Callable[..., MavSim], open_link: Callable[[], MavlinkLink]
) -> None:
    sim = make_sim()
    link = open_link()
    link.wait_heartbeat(5)
    ack = link.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (33, 100_000))
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert sim.message_interval_s(33) == pytest.approx(0.1)

    with pytest.raises(CommandDenied) as denied:  # take-off while disarmed
        link.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 10))
    assert denied.value.result == mavlink.MAV_RESULT_FAILED and denied.value.permanent

    with pytest.raises(CommandDenied) as unsupported:
        link.command_int(mavlink.MAV_CMD_DO_SET_ROI_NONE)
    assert unsupported.value.result == mavlink.MAV_RESULT_UNSUPPORTED

    sim.ignore_command(mavlink.MAV_CMD_DO_SET_MODE)
    started = time.monotonic()
    with pytest.raises(CommandTimeout) as timeout:
        link.set_mode("GUIDED")
    # Three attempts of 0.3 s, the retransmissions counting up `confirmation`.
    assert 0.85 < time.monotonic() - started < 2.0
    assert sim.commands_seen(mavlink.MAV_CMD_DO_SET_MODE) == [0, 1, 2]
    assert timeout.value.attempts == 3 and not timeout.value.permanent

    sim.ignore_command(mavlink.MAV_CMD_DO_SET_MODE, ignore=False)
    link.set_mode("GUIDED")
    assert sim.mode == "GUIDED" and link.heartbeat is not None
    assert link.heartbeat.mode == "GUIDED"


def test_parameters(make_sim: Callable[..., MavSim], open_link: Callable[[], MavlinkLink]) -> None:
    sim = make_sim()
    link = open_link()
    link.wait_heartbeat(5)
    assert link.param_get("WPNAV_SPEED") == 1000.0
    assert link.param_set("FENCE_ALT_MAX", 75.5) == 75.5
    assert sim.param("FENCE_ALT_MAX") == 75.5
    # The type comes from the vehicle's PARAM_VALUE: FENCE_ENABLE is an INT8.
    assert link.param_set("FENCE_ENABLE", 1) == 1.0
    with pytest.raises(ValueError, match="does not fit"):
        link.param_set("FENCE_ENABLE", 1000)
    # An unknown parameter gets no answer at all.
    with pytest.raises(ParamTimeout) as caught:
        link.param_get("NO_SUCH_PARAM")
    assert not caught.value.permanent


def test_px4_integer_parameters_are_sent_bytewise(
    make_sim: Callable[..., MavSim], open_link: Callable[[], MavlinkLink]
) -> None:
    sim = make_sim(autopilot="px4")
    link = open_link()
    assert link.wait_heartbeat(5).autopilot is Autopilot.PX4
    assert link.param_get("GF_ACTION") == 2.0
    assert link.param_set("GF_ACTION", 3) == 3.0
    assert sim.param("GF_ACTION") == 3.0  # not 4.2e-45, which a float cast would have made


def test_a_fence_upload_survives_a_lost_message_and_reads_back(
    make_sim: Callable[..., MavSim], open_link: Callable[[], MavlinkLink]
) -> None:
    sim = make_sim()
    link = open_link()
    link.wait_heartbeat(5)
    items = fence_polygon_items(AREA)
    sim.drop_incoming("MISSION_COUNT")  # the first MISSION_COUNT is lost: we send it again
    sim.drop_incoming("MISSION_ITEM_INT")  # so is the first item: the vehicle asks again
    link.upload_mission(items, FENCE)
    assert sim.mission_items(FENCE) == items
    assert sim.fence_polygons() == [[tuple(p) for p in AREA[:4]]]
    assert link.download_mission(FENCE) == items

    waypoint = MissionItem(command=mavlink.MAV_CMD_NAV_WAYPOINT, x=481100000, y=128600000)
    with pytest.raises(MissionRejected) as refused:
        link.upload_mission([waypoint], FENCE)
    assert refused.value.result == mavlink.MAV_MISSION_UNSUPPORTED and refused.value.permanent
    assert sim.mission_items(FENCE) == items

    link.upload_mission([], FENCE)  # an empty list clears it
    assert sim.mission_items(FENCE) == []


def test_link_loss_is_detected_and_recovery_too(make_sim: Callable[..., MavSim], port: int) -> None:
    sim = make_sim()
    lost, regained = threading.Event(), threading.Event()
    with MavlinkLink(
        f"udpout:127.0.0.1:{port}",
        link_timeout_s=0.5,
        on_link_lost=lost.set,
        on_link_regained=regained.set,
    ) as link:
        link.wait_heartbeat(5)
        # Heartbeats at 10 Hz, so that half a second without one means something.
        link.set_message_interval(mavlink.MAVLINK_MSG_ID_HEARTBEAT, 10.0)
        wait_until(lambda: sim.message_interval_s(0) == 0.1, what="the heartbeat rate")
        time.sleep(0.6)  # a link that would flap at this rate flaps now
        assert link.link_ok and not lost.is_set()
        sim.cut_link()
        cut = time.monotonic()
        assert lost.wait(3.0)
        # Lost half a second after the last heartbeat, give or take the watchdog's tick.
        assert 0.35 < time.monotonic() - cut < 0.5 + 0.25
        assert not link.link_ok
        with pytest.raises(LinkLost) as caught:
            link.command_long(mavlink.MAV_CMD_DO_SET_ROI_NONE)
        assert not caught.value.permanent
        sim.restore_link()
        assert regained.wait(3.0) and link.link_ok


def test_a_tcp_link(make_sim: Callable[..., MavSim]) -> None:
    tcp = free_tcp_port()
    make_sim(connection=f"tcpin:127.0.0.1:{tcp}")
    with MavlinkLink(f"tcp:127.0.0.1:{tcp}", command_timeout_s=0.5) as link:
        assert link.wait_heartbeat(5).mav_type == mavlink.MAV_TYPE_QUADROTOR
        assert link.param_get("BATT_CAPACITY") == 5000.0
    # The first client hung up: the simulator takes the next one.
    with MavlinkLink(f"tcp:127.0.0.1:{tcp}", command_timeout_s=0.5) as link:
        assert link.wait_heartbeat(5).system_id == 1
        assert link.param_get("WPNAV_SPEED") == 1000.0


def test_a_tcp_server_that_is_not_up_yet_may_be_later() -> None:
    with pytest.raises(LinkError, match="cannot connect") as caught:
        MavlinkLink(f"tcp:127.0.0.1:{free_tcp_port()}").open()
    assert not caught.value.permanent


def test_long_status_texts_are_joined_and_ground_stations_ignored() -> None:
    port = free_udp_port()
    vehicle = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=7)
    try:
        with MavlinkLink(f"udpout:127.0.0.1:{port}") as link:
            # Wait for the link's heartbeat so the fake vehicle knows where to answer.
            wait_until(lambda: vehicle.recv_match(type="HEARTBEAT"), what="the link's heartbeat")
            # Another ground station's heartbeat first: not a vehicle to lock onto.
            gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=200)
            vehicle.mav.srcSystem = 7
            vehicle.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            vehicle.mav.heartbeat_send(
                mavlink.MAV_TYPE_HEXAROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 5, 3
            )
            beat = link.wait_heartbeat(5)
            assert (beat.system_id, beat.mode) == (7, "LOITER")
            text = "PreArm: " + "x" * 60
            vehicle.mav.statustext_send(2, text[:50].encode(), 9, 0)
            vehicle.mav.statustext_send(2, text[50:].encode(), 9, 1)
            lines = wait_until(lambda: link.status_texts(), what="the status text")
            assert [t.text for t in lines] == [text]
            gcs.close()
    finally:
        vehicle.close()


def test_a_serial_port_that_cannot_be_opened_is_a_permanent_error() -> None:
    link = MavlinkLink("serial:/dev/cpcc-no-such-port:57600")
    # Without pyserial installed the reason is the missing package, otherwise the device.
    with pytest.raises(LinkError, match=r"pyserial|cpcc-no-such-port") as caught:
        link.open()
    assert caught.value.permanent
