"""MavSim's camera (MAV_COMP_ID_CAMERA) over the MAVLink camera protocol: CAMERA_INFORMATION on
request, a single image on MAV_CMD_IMAGE_START_CAPTURE announced by CAMERA_IMAGE_CAPTURED, and
the image itself fetched over HTTP from the URL it names."""

from __future__ import annotations

import io
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from PIL import Image

from fleet.geo import distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from fleet.simulation import render_camera
from fleet.simulation.sensors import SensorSpec
from tests.fleet.mavlink.conftest import DEPOT, wait_until
from tests.fleet.mavlink.test_mavsim_guided import Station

SPEED = 40.0
SEED = 3
CAMERA = mavlink.MAV_COMP_ID_CAMERA


def from_camera(msg: Any) -> bool:
    return bool(msg.get_srcComponent() == CAMERA)


def camera_command(gcs: Station, command: int, *params: float) -> int:
    values = [*params, *[0.0] * (7 - len(params))]
    gcs.mav.command_long_send(1, CAMERA, command, 0, *values)
    ack = gcs.wait("COMMAND_ACK", lambda m: m.command == command and from_camera(m))
    return int(ack.result)


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=SPEED, field_seed=SEED, payload=True)


@pytest.fixture
def gcs(port: int, sim: MavSim) -> Iterator[Station]:
    station = Station(port)
    yield station
    station.close()


def test_camera_information_on_request(sim: MavSim, gcs: Station) -> None:
    beat = gcs.wait("HEARTBEAT", from_camera)
    assert beat.type == mavlink.MAV_TYPE_CAMERA
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_INVALID
    information = mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION
    assert camera_command(gcs, mavlink.MAV_CMD_REQUEST_MESSAGE, information) == 0
    info = gcs.wait("CAMERA_INFORMATION", from_camera)
    assert (info.resolution_h, info.resolution_v) == (640, 480)
    assert info.flags & mavlink.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
    assert bytes(info.vendor_name).rstrip(b"\0") == b"CPCC"
    # The older command, and a request to every component (the camera answers it).
    assert camera_command(gcs, mavlink.MAV_CMD_REQUEST_CAMERA_INFORMATION, 1) == 0
    gcs.wait("CAMERA_INFORMATION", from_camera)
    gcs.mav.command_long_send(
        1, 0, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, information, 0, 0, 0, 0, 0, 0
    )
    gcs.wait("COMMAND_ACK", lambda m: from_camera(m) and m.result == 0)
    gcs.wait("CAMERA_INFORMATION", from_camera)


def test_capture_an_image_and_fetch_it(sim: MavSim, gcs: Station) -> None:
    gcs.take_off(sim, 30)
    target = offset(DEPOT, north_m=-200, east_m=150, up_m=30)
    assert gcs.guided_item(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, target, 30) == 0
    wait_until(lambda: distance_m(sim.position(), target) < 0.5, what="the photo spot")

    start = mavlink.MAV_CMD_IMAGE_START_CAPTURE
    assert camera_command(gcs, start, 0, 0, 1) == mavlink.MAV_RESULT_ACCEPTED
    captured = gcs.wait("CAMERA_IMAGE_CAPTURED", from_camera)
    assert (captured.image_index, captured.capture_result) == (0, 1)
    assert abs(captured.lat - round(target.lat * 1e7)) < 100  # a centimetre or so
    assert abs(captured.lon - round(target.lng * 1e7)) < 100
    assert abs(captured.relative_alt - 30_000) < 100 and captured.time_utc > 1_600_000_000e6
    url = captured.file_url
    assert url == f"http://127.0.0.1:{sim.camera_port}/images/0.png"

    with urllib.request.urlopen(url, timeout=10) as response:
        assert response.headers["Content-Type"] == "image/png"
        png = response.read()
    assert Image.open(io.BytesIO(png)).size == (640, 480)
    # The catalog's "Camera 640x480" at the capture's place, time and heading, in mavsim's world.
    shot = sim.camera_captures()[0].shot
    assert distance_m(shot.position, target) < 0.5
    spec = SensorSpec(
        "Camera 640x480",
        "camera",
        "",
        {"width": 640, "height": 480, "format": "png", "view": "front"},
    )
    heading = shot.heading_deg or 0.0  # still turning onto the spot, or facing north
    # Its caption prints the capture's UTC time, as CAMERA_IMAGE_CAPTURED reports it.
    assert png == render_camera(
        spec,
        shot.position,
        shot.time_s,
        seed=SEED,
        heading_deg=heading,
        epoch_s=captured.time_utc / 1e6,
    )

    # The next image gets the next index; one not taken is not there.
    assert camera_command(gcs, start, 0, 0, 1) == 0
    assert gcs.wait("CAMERA_IMAGE_CAPTURED", from_camera).image_index == 1
    with pytest.raises(urllib.error.HTTPError) as missing:
        urllib.request.urlopen(url.replace("/0.png", "/7.png"), timeout=10)
    assert missing.value.code == 404
    # Interval capture (param3 = 0: until stopped) is not simulated, and says so.
    assert camera_command(gcs, start, 0, 2, 0) == mavlink.MAV_RESULT_UNSUPPORTED
