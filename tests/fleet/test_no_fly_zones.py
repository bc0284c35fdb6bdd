"""No-fly zones (issue 24): the mapper serves no task inside a zone (between its altitudes)
and says why, and a zone drawn while a task waits for its RV routes the task again
(tests/fleet/mavlink/test_autopilot_airspace.py: what the autopilots receive)."""

from __future__ import annotations

import pytest
from django.core.exceptions import ValidationError
from shapely.geometry import Polygon

from fleet.models import NoFlyZone
from missions.models import TaskStatus, VVStatus
from tests.factories import VehicleFactory
from tests.fleet.mavlink.conftest import AREA, DEPOT
from vvm_worker.mapping import ExclusionZone, VehicleCaps, map_task
from vvm_worker.planning import AroundZones
from vvm_worker.runtime.types import TaskRequest
from vvm_worker.services import fleet_airspace, no_fly_zone_save, vv_submit

# A square inside Heli One's area (tests/factories' AREA_ONE), around (48.1111, 12.8619).
ZONE = [[48.1105, 12.8610], [48.1105, 12.8625], [48.1115, 12.8625], [48.1115, 12.8610],
        [48.1105, 12.8610]]  # fmt: skip


def _polygon(ring: list[list[float]]) -> Polygon:
    return Polygon([(lng, lat) for lat, lng in ring])


def _caps(zones: tuple[ExclusionZone, ...]) -> VehicleCaps:
    return VehicleCaps(
        id=1,
        name="Heli One",
        area=_polygon(AREA),
        min_altitude_m=0.0,
        max_altitude_m=120.0,
        sensors=frozenset({"CO2"}),
        active=True,
        position=DEPOT,
        max_speed_mps=10.0,
        no_fly=zones,
    )


def _task(alt: float) -> TaskRequest:
    return TaskRequest(lat=48.1111, lng=12.8619, alt=alt, tolerance_m=2.0, sensors=("CO2",))


def test_the_mapper_serves_no_task_inside_a_zone_and_says_why() -> None:
    band = ExclusionZone(_polygon(ZONE), min_altitude_m=0.0, max_altitude_m=60.0)
    fleet = [_caps((band,))]
    refused = map_task(_task(50), fleet)
    assert refused.reason == (
        "no vehicle can serve the task at (48.111100, 12.861900) at 50 m: it is inside a "
        "no-fly zone"
    )
    assert "Heli One" not in refused.reason  # nor the zone's name or owner
    assert map_task(_task(80), fleet).candidates == tuple(fleet)  # above the zone's band
    assert map_task(_task(50), [_caps(())]).candidates  # no zone, no refusal


@pytest.mark.django_db
def test_a_zone_needs_a_closed_ring_and_altitudes_the_right_way_up(vvm_factory) -> None:
    with pytest.raises(ValidationError) as refused:
        no_fly_zone_save(zone=NoFlyZone(name="Open", area=ZONE[:-1]), vvm=vvm_factory())
    assert refused.value.message_dict == {
        "area": ["must be closed: the last point repeats the first"]
    }
    with pytest.raises(ValidationError) as refused:
        no_fly_zone_save(
            zone=NoFlyZone(name="Upside", area=ZONE, min_altitude_m=50, max_altitude_m=10),
            vvm=vvm_factory(),
        )
    assert refused.value.message_dict == {"max_altitude_m": ["must not be below min_altitude_m (50 m)"]}  # fmt: skip
    assert not NoFlyZone.objects.exists()


PROGRAM = """
var co2 = VV.sensor.get('CO2');
try {
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                   tolerance: 2, sensors: [co2]});
} catch (e) { VV.storage.store('rejected', [e.name, e.message]); }
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1125, 12.8630, 50),
                 tolerance: 2, sensors: [co2]});
"""


@pytest.mark.django_db
def test_a_vv_asking_for_a_point_in_a_zone_gets_the_reason_and_goes_on(
    platform, ground_station, customer_a
) -> None:
    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    no_fly_zone_save(zone=NoFlyZone(name="Prison", area=ZONE), vvm=platform.vvm)
    vv = vv_submit(customer=customer_a, name="VV", program=PROGRAM, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    name, message = vv.storage.get(key="rejected").value
    assert name == "TaskRejectedError" and message.endswith("it is inside a no-fly zone")
    assert "Prison" not in message
    statuses = list(vv.tasks.order_by("q").values_list("status", flat=True))
    assert statuses == [TaskStatus.REJECTED, TaskStatus.DONE]


@pytest.mark.django_db
def test_a_zone_drawn_while_a_task_waits_for_its_rv_routes_it_again(
    platform, ground_station, customer_a
) -> None:
    heli = VehicleFactory(name="Heli One")
    vv = vv_submit(customer=customer_a, name="VV", program=PROGRAM, vvm=platform.vvm)
    platform.drain()  # routed to Heli One, whose loop does not run yet
    task = vv.tasks.get()
    assert (task.status, task.vehicle) == (TaskStatus.OPEN, heli)
    no_fly_zone_save(zone=NoFlyZone(name="Prison", area=ZONE), vvm=platform.vvm)
    platform.add_vehicle_loop(heli)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    name, message = vv.storage.get(key="rejected").value
    assert name == "TaskRejectedError" and message.endswith("it is inside a no-fly zone")
    statuses = list(vv.tasks.order_by("q").values_list("status", flat=True))
    assert statuses == [TaskStatus.REJECTED, TaskStatus.DONE]


@pytest.mark.django_db
def test_a_worker_told_of_a_new_zone_flies_round_it_and_its_planner_keeps_its_state(
    platform,
) -> None:
    rig = platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    assert not rig.loop.airspace
    state = rig.loop.planner.state()
    no_fly_zone_save(zone=NoFlyZone(name="Prison", area=ZONE), vvm=platform.vvm)
    airspace = fleet_airspace()
    assert airspace.holds(TaskRequest(48.1111, 12.8619, 50.0, 2.0, ()))
    rig.fly_in(airspace)
    assert rig.loop.airspace is airspace
    assert isinstance(rig.loop.planner.cost, AroundZones)
    assert rig.loop.planner.state() == state
    planner = rig.loop.planner
    rig.fly_in(fleet_airspace())  # the same zones: the same airspace, nothing to change
    assert rig.loop.planner is planner
