"""Every RV's autopilot receives the provider's no-fly zones (exclusion polygons) and rally
points (issue 24): the fence MavSim gets over loopback."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from fleet.geo import Position
from fleet.mavlink import MavlinkDriver, MavSim
from fleet.mavlink.mission import exclusion_polygons, inclusion_polygons
from fleet.mavlink.wire import mavlink
from fleet.models import NoFlyZone, RallyPoint
from fleet.selectors import vehicle_fence
from tests.factories import VehicleFactory
from tests.fleet.mavlink.conftest import AREA, DEPOT, SPEC, sim_clock
from tests.fleet.test_no_fly_zones import ZONE
from vvm_worker.services import no_fly_zone_save, rally_point_save


@pytest.mark.django_db
def test_the_autopilot_receives_the_zones_and_the_rally_points(
    make_sim: Callable[..., MavSim], port: int, vvm_factory
) -> None:
    heli = VehicleFactory(name="Heli One", area=AREA, min_altitude_m=0, max_altitude_m=120)
    vvm = vvm_factory()
    no_fly_zone_save(zone=NoFlyZone(name="Prison", area=ZONE), vvm=vvm)
    # A zone only up to 30 m: the platform keeps RVs out of it; an autopilot's exclusion
    # polygon would hold at every altitude, so it does not get it.
    no_fly_zone_save(
        zone=NoFlyZone(name="Crowd", area=AREA, min_altitude_m=0, max_altitude_m=30), vvm=vvm
    )
    rally_point_save(point=RallyPoint(name="Field", lat=48.112, lng=12.862, alt=15), vvm=vvm)
    fence = vehicle_fence(vehicle=heli)
    assert fence.exclusions == [ZONE]
    sim = make_sim()
    driver = MavlinkDriver(
        f"udpout:127.0.0.1:{port}",
        spec=SPEC,
        depot=DEPOT,
        area=fence.area,
        min_altitude_m=fence.min_altitude_m,
        max_altitude_m=fence.max_altitude_m,
        exclusions=fence.exclusions,
        rally=fence.rally,
        clock=sim_clock(),
        command_timeout_s=0.5,
    )
    try:
        driver.connect(timeout_s=5.0)
        items = sim.mission_items(mavlink.MAV_MISSION_TYPE_FENCE)
        assert inclusion_polygons(items) == [[tuple(p) for p in AREA[:-1]]]
        assert exclusion_polygons(items) == [[tuple(p) for p in ZONE[:-1]]]
        (rally,) = sim.mission_items(mavlink.MAV_MISSION_TYPE_RALLY)
        assert rally.command == mavlink.MAV_CMD_NAV_RALLY_POINT
        assert (rally.lat, rally.lng, rally.z) == (48.112, 12.862, 15.0 - DEPOT.alt)
        assert driver.fence is not None and driver.fence.rally == ((48.112, 12.862, 15.0),)
    finally:
        driver.close()
    assert Position(48.112, 12.862, 15.0) == fence.rally[0]
