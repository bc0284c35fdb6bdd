"""MavSim flown by MAVSDK (the native binding, mavsdk 4.x, as its own ground station): connect,
arm, take off, go to a point in GUIDED (DO_REPOSITION), a two-waypoint mission in AUTO
(mission_raw: MAVSDK's mission plugin does not put ArduPilot's home into item 0), and RTL to
the landing, asserted on mavsim's own state; and a photo through MAVSDK's camera plugin."""

from __future__ import annotations

import asyncio
import urllib.request
from collections.abc import Callable
from typing import Any

import mavsdk.asyncio as mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.camera import CameraAsync
from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import DEPOT
from tests.polling import wait_until_async

SPEED = 40.0
GROUND_AMSL_M = 350.0
GOTO = offset(DEPOT, north_m=120, east_m=-80, up_m=25)
A = offset(DEPOT, north_m=-150, east_m=60, up_m=30)
B = offset(DEPOT, north_m=-60, east_m=200, up_m=20)
HOLD_S = 20.0  # at the first waypoint: half a second of the test at SPEED


def waypoint(seq: int, where: Position, hold_s: float = 0.0) -> Any:
    return MissionItem(
        seq=seq,
        frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        command=mavlink.MAV_CMD_NAV_WAYPOINT,
        current=1 if seq == 0 else 0,  # MAVSDK wants the first item marked current
        autocontinue=1,
        param1=hold_s,
        x=round(where.lat * 1e7),
        y=round(where.lng * 1e7),
        z=where.alt,
        mission_type=0,
    )


async def test_mavsdk_flies_guided_a_mission_and_home(
    make_sim: Callable[..., MavSim], port: int
) -> None:
    sim = make_sim(speed=SPEED, ground_amsl_m=GROUND_AMSL_M)
    config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
    async with mavsdk.Mavsdk(config) as drone:
        await drone.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = await drone.first_autopilot(timeout_s=10.0)
        assert system is not None
        assert await system.autopilot_type() == mavsdk.Autopilot.ARDUPILOT
        action = ActionAsync(system)
        missions = MissionRawAsync(system)

        await action.set_takeoff_altitude(15.0)
        await action.arm()
        assert sim.armed
        await action.takeoff()  # GUIDED, then NAV_TAKEOFF
        await wait_until_async(
            lambda: abs(sim.position().alt - 15.0) < 0.05, what="the take-off", timeout=10
        )
        assert sim.mode == "GUIDED"

        # goto_location: DO_REPOSITION, the altitude above mean sea level.
        await action.goto_location(GOTO.lat, GOTO.lng, GROUND_AMSL_M + GOTO.alt, 0.0)
        await wait_until_async(
            lambda: distance_m(sim.position(), GOTO) < 0.5, what="the goto point", timeout=10
        )

        # A raw mission: item 0 is home on ArduPilot, then the two waypoints.
        await missions.upload_mission([waypoint(0, DEPOT), waypoint(1, A, HOLD_S), waypoint(2, B)])
        assert len(sim.mission_items(mavlink.MAV_MISSION_TYPE_MISSION)) == 3
        await missions.start_mission()
        await wait_until_async(lambda: sim.mode == "AUTO", what="AUTO", timeout=10)
        await wait_until_async(
            lambda: distance_m(sim.position(), A) < 0.5, what="the first waypoint", timeout=10
        )
        await wait_until_async(
            lambda: distance_m(sim.position(), B) < 0.5, what="the second waypoint", timeout=10
        )
        # MAVSDK sees the mission done from MISSION_CURRENT and MISSION_ITEM_REACHED.
        await wait_until_async(
            missions.is_mission_finished, timeout=5, what="MAVSDK to see it finished", interval=0.05
        )
        progress = await missions.mission_progress()
        assert (progress.current, progress.total) == (3, 3)

        await action.return_to_launch()
        assert sim.mode == "RTL"
        await wait_until_async(
            lambda: sim.on_ground and not sim.armed, what="the landing", timeout=10
        )
        assert distance_m(sim.position(), DEPOT) < 0.5


async def test_mavsdk_takes_a_photo(make_sim: Callable[..., MavSim], port: int) -> None:
    sim = make_sim(speed=SPEED, payload=True)
    config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
    async with mavsdk.Mavsdk(config) as drone:
        await drone.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = await drone.first_autopilot(timeout_s=10.0)
        assert system is not None
        camera = CameraAsync(system)

        # MAVSDK finds the camera by its HEARTBEAT and asks for CAMERA_INFORMATION.
        async def listed() -> Any:
            return (await camera.camera_list()).cameras

        cameras = await wait_until_async(
            listed, timeout=10, what="MAVSDK to find the camera", interval=0.05
        )
        assert [(c.component_id, c.vendor_name) for c in cameras] == [(100, "CPCC")]
        assert (cameras[0].horizontal_resolution_px, cameras[0].vertical_resolution_px) == (
            640,
            480,
        )

        captures = camera.subscribe_capture_info()
        next_capture = asyncio.ensure_future(anext(captures))
        await asyncio.sleep(0)  # the subscription is made before the photo is asked for
        await camera.take_photo(100)
        info = await asyncio.wait_for(next_capture, timeout=10.0)
        await captures.aclose()
        assert info.is_success and info.index == 0
        assert abs(info.position.latitude_deg - DEPOT.lat) < 1e-6
        with urllib.request.urlopen(info.file_url, timeout=10) as response:
            png = response.read()
        assert png.startswith(b"\x89PNG") and len(sim.camera_captures()) == 1
