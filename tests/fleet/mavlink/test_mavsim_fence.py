"""MavSim enforcing its geofence as ArduCopter does: FENCE_ENABLE, the maximum altitude and the
inclusion polygons uploaded with the mission protocol; a breach is reported (FENCE_STATUS,
"Polygon fence breached") and FENCE_ACTION follows (RTL, LAND or only the report); GUIDED
targets outside the fence are refused."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from fleet.geo import distance_m, offset
from fleet.mavlink import MavSim, fence_polygon_items
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import AREA, DEPOT, wait_until
from tests.fleet.mavlink.test_mavsim_auto import item, upload
from tests.fleet.mavlink.test_mavsim_guided import Station

SPEED = 40.0
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
OUTSIDE = offset(DEPOT, north_m=300, east_m=0, up_m=20)  # AREA ends 55 m north of the depot


def upload_fence(
    gcs: Station, ring: list[list[float]], no_fly: list[list[float]] | None = None
) -> None:
    items = fence_polygon_items(ring)
    if no_fly is not None:
        items += fence_polygon_items(no_fly, exclusion=True, first_seq=len(items))
    gcs.mav.mission_count_send(1, 1, len(items), FENCE)
    for _ in items:
        request = gcs.wait("MISSION_REQUEST_INT", lambda m: m.mission_type == FENCE)
        items[request.seq].send(gcs.mav, 1, 1, FENCE)
    assert gcs.wait("MISSION_ACK", lambda m: m.mission_type == FENCE).type == 0


def set_param(gcs: Station, name: str, value: float) -> None:
    gcs.conn.param_set_send(name, value)
    gcs.wait("PARAM_VALUE", lambda m: m.param_id == name and m.param_value == value)


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=SPEED)


@pytest.fixture
def gcs(port: int, sim: MavSim) -> Iterator[Station]:
    station = Station(port)
    yield station
    station.close()


def test_leaving_the_polygon_returns_to_launch(sim: MavSim, gcs: Station) -> None:
    gcs.wait("HEARTBEAT")
    upload_fence(gcs, AREA)
    set_param(gcs, "FENCE_ENABLE", 1)
    gcs.take_off(sim, 20)

    # A GUIDED target outside is refused (ArduCopter's set_destination); no breach follows.
    relative = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    assert gcs.guided_item(relative, OUTSIDE, 20) == mavlink.MAV_MISSION_ERROR
    assert "Guided: destination outside Polygon fence" in sim.texts_sent()
    reposition = gcs.command_int(
        mavlink.MAV_CMD_DO_REPOSITION, relative, -1, 0, x=OUTSIDE.lat, y=OUTSIDE.lng, z=20
    )
    assert reposition == mavlink.MAV_RESULT_FAILED
    assert sim.fence_status().count == 0

    # A mission may lead out: the breach turns it home (FENCE_ACTION 1, RTL).
    upload(
        gcs,
        [
            item(mavlink.MAV_CMD_NAV_TAKEOFF, alt=20),
            item(mavlink.MAV_CMD_NAV_WAYPOINT, OUTSIDE, 20),
        ],
    )
    gcs.conn.set_mode("AUTO")
    status = gcs.wait("FENCE_STATUS", lambda m: m.breach_status == 1)
    assert (status.breach_count, status.breach_type) == (1, mavlink.FENCE_BREACH_BOUNDARY)
    assert status.breach_time > 0
    text = next(t for t in gcs.texts if "breached" in t.text)
    assert (text.text, text.severity) == ("Polygon fence breached", mavlink.MAV_SEVERITY_NOTICE)
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 6)  # RTL
    assert sim.mode == "RTL"
    # Back inside on the way home, the breach is over; then it lands and disarms.
    gcs.wait("FENCE_STATUS", lambda m: m.breach_status == 0 and m.breach_count == 1)
    wait_until(lambda: sim.on_ground and not sim.armed, what="the landing")
    assert distance_m(sim.position(), DEPOT) < 0.5


def test_above_the_maximum_altitude(sim: MavSim, gcs: Station) -> None:
    gcs.wait("HEARTBEAT")
    set_param(gcs, "FENCE_ENABLE", 1)
    set_param(gcs, "FENCE_ALT_MAX", 40)
    set_param(gcs, "FENCE_ACTION", 0)  # report only
    gcs.take_off(sim, 30)
    high = offset(DEPOT, north_m=10, east_m=0, up_m=50)
    assert (
        gcs.guided_item(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, high, 50)
        == mavlink.MAV_MISSION_ERROR
    )
    assert "Guided: destination outside Max Alt fence" in sim.texts_sent()

    # The fence comes down below the vehicle: reported only.
    set_param(gcs, "FENCE_ALT_MAX", 20)
    status = gcs.wait("FENCE_STATUS", lambda m: m.breach_status == 1)
    assert status.breach_type == mavlink.FENCE_BREACH_MAXALT
    assert "Max Alt fence breached" in sim.texts_sent()
    assert sim.mode == "GUIDED"

    # FENCE_ACTION 2 lands where it is at the next breach.
    set_param(gcs, "FENCE_ALT_MAX", 100)
    gcs.wait("FENCE_STATUS", lambda m: m.breach_status == 0)
    set_param(gcs, "FENCE_ACTION", 2)
    here = sim.position()
    set_param(gcs, "FENCE_ALT_MAX", 20)
    assert gcs.wait("FENCE_STATUS", lambda m: m.breach_status == 1).breach_count == 2
    gcs.wait("HEARTBEAT", lambda m: m.custom_mode == 9)  # LAND
    wait_until(lambda: sim.on_ground and not sim.armed, what="the landing")
    assert distance_m(sim.position(), here.with_alt(0)) < 0.5

    # FENCE_STATUS on request, as a GCS polls it.
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_FENCE_STATUS) == 0
    assert gcs.wait("FENCE_STATUS").breach_count == 2


def test_a_no_fly_zone_inside_the_area(sim: MavSim, gcs: Station) -> None:
    # An exclusion polygon 100 to 200 m south of the depot, 100 m wide.
    corners = [(-100, -50), (-100, 50), (-200, 50), (-200, -50)]
    zone = [offset(DEPOT, north_m=n, east_m=e) for n, e in corners]
    gcs.wait("HEARTBEAT")
    upload_fence(gcs, AREA, [[p.lat, p.lng] for p in zone])
    set_param(gcs, "FENCE_ENABLE", 1)
    gcs.take_off(sim, 20)
    inside = offset(DEPOT, north_m=-150, east_m=0, up_m=20)
    relative = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    assert gcs.guided_item(relative, inside, 20) == mavlink.MAV_MISSION_ERROR

    # Beyond the zone, still in the area: the straight way there crosses the zone.
    beyond = offset(DEPOT, north_m=-300, east_m=0, up_m=20)
    assert gcs.guided_item(relative, beyond, 20) == mavlink.MAV_MISSION_ACCEPTED
    status = gcs.wait("FENCE_STATUS", lambda m: m.breach_status == 1)
    assert status.breach_type == mavlink.FENCE_BREACH_BOUNDARY
    assert "Polygon fence breached" in sim.texts_sent()
    assert sim.mode == "RTL"
    assert distance_m(sim.position(), DEPOT) < 110  # turned back at the zone's edge
    wait_until(lambda: sim.on_ground and not sim.armed, what="the landing")
