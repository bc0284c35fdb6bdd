"""RV workers driving a rover and diving a submarine over real MAVLink links: the worker's
MAVLink driver against MavSim as ArduRover (frame "rover") and ArduSub ("sub") on loopback,
each serving a VV to the end with every reading, the rest of the platform as in production."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from fleet.geo import Position, distance_m
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from fleet.models import Driver, Vehicle
from fleet.simulation.vehicle import VehicleSpec
from missions.models import JournalEntry, TaskStatus, VirtualVehicle, VVStatus
from tests.fleet.mavlink.conftest import free_udp_port
from tests.polling import wait_until
from tests.vvm_worker.test_distributed import FIELD, all_ended, load

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

SPEED = 25.0  # the simulators' time acceleration, as the workers' (tests/live.py)
DEPOT = [48.1135, 12.8600, 0]


def _program(points: Sequence[tuple[float, float, float]]) -> str:
    """A VV that reads the thermometer at each point and stores it as p0, p1, ..."""
    where = ", ".join(f"new VV.types.LatLngAlt({lat}, {lng}, {alt})" for lat, lng, alt in points)
    return (
        "var t = VV.sensor.get('Thermometer');\n"
        f"var points = [{where}];\n"
        "for (var n = 0; n < points.length; ++n) {\n"
        "  VV.task.execute({ type: 'point', position: points[n], tolerance: 2, sensors: [t] },\n"
        "    function (data) { VV.storage.store('p' + n, data[0]); });\n"
        "}\n"
    )


def _scenario(
    vehicle: dict[str, Any], points: Sequence[tuple[float, float, float]], tmp_path: Path
) -> dict[str, Any]:
    program = tmp_path / "vv.js"  # an absolute path: ``load`` keeps it
    program.write_text(_program(points))
    return {
        "name": f"A {vehicle['kind']} vehicle over MAVLink",
        "ground_stations": [{"name": "GS Base", "position": [48.1132, 12.8598, 0]}],
        "vehicles": [{"depot": DEPOT, "area": FIELD, "sensors": ["Thermometer", "GPS"], **vehicle}],
        "customers": [{"name": "Customer A", "max_parallel_vvs": 5}],
        "vvs": [{"customer": "Customer A", "name": "VV 1", "program": str(program)}],
    }


def _mavsim(vehicle: Vehicle, frame: str) -> MavSim:
    """Make ``vehicle`` a MAVLink vehicle and start its simulated autopilot of ``frame``,
    moving as the vehicle's record says, which its worker will reach."""
    port = free_udp_port()
    vehicle.driver, vehicle.driver_url = Driver.MAVLINK, f"udpout:127.0.0.1:{port}"
    vehicle.save(update_fields=["driver", "driver_url"])
    spec = VehicleSpec(
        max_speed_mps=vehicle.max_speed_mps,
        climb_rate_mps=vehicle.climb_rate_mps,
        battery_s=vehicle.battery_s,
        dive_rate_mps=vehicle.dive_rate_mps,
        turn_rate_dps=vehicle.turn_rate_dps,
    )
    sim = MavSim(
        f"udpin:127.0.0.1:{port}",
        spec=spec,
        depot=vehicle.depot,
        speed=SPEED,
        name=vehicle.name,
        frame=frame,
    )
    return sim.start()


@pytest.fixture
def sims() -> Iterator[list[MavSim]]:
    started: list[MavSim] = []
    yield started
    for sim in started:
        sim.stop()


def _serve_to_the_end(workers, vehicle: Vehicle) -> VirtualVehicle:
    workers.env["CPCC_SIM_SPEED"] = "0"
    workers.env["CPCC_STANDBY_S"] = "1"  # real seconds waiting for work before going home
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", vehicle.name)
    wait_until(all_ended, timeout=180, what="VV 1 to end", details=workers.logs)
    return VirtualVehicle.objects.get()


def _assert_every_reading_where_asked(vv: VirtualVehicle, vehicle: Vehicle, count: int) -> None:
    assert vv.status == VVStatus.FINISHED, vv.error
    assert set(vv.storage.values_list("key", flat=True)) == {f"p{n}" for n in range(count)}
    done = list(vv.tasks.filter(status=TaskStatus.DONE))
    assert len(done) == count and all(t.vehicle == vehicle for t in done)
    assert JournalEntry.objects.filter(vv=vv).count() == count, "every reading exactly once"
    for task in done:  # where the vehicle was as it read: within the task's tolerance
        where = task.readings[0]["position"]
        assert distance_m(Position(where["lat"], where["lng"], where["alt"]), task.position) <= (
            task.tolerance_m
        )


def test_an_rv_worker_drives_a_rover_over_mavlink_through_a_vv(
    workers, sims, tmp_path: Path, monkeypatch
) -> None:
    points = [(48.1110, 12.8610, 0), (48.1100, 12.8635, 0), (48.1125, 12.8650, 0)]
    rover = {"name": "Rover", "kind": "ground", "max_speed_mps": 5, "turn_rate_dps": 90}
    load(_scenario(rover, points, tmp_path), tmp_path, monkeypatch)
    vehicle = Vehicle.objects.get(name="Rover")
    assert vehicle.kind == "ground"
    sims.append(sim := _mavsim(vehicle, "rover"))

    vv = _serve_to_the_end(workers, vehicle)
    _assert_every_reading_where_asked(vv, vehicle, len(points))
    assert all(t.alt == 0 for t in vv.tasks.all())
    assert sim.commands_seen(mavlink.MAV_CMD_NAV_TAKEOFF) == []  # it drives off
    # Its geofence: the area's polygon only, no altitude.
    (polygon,) = sim.fence_polygons()
    assert [(round(a, 6), round(b, 6)) for a, b in polygon] == [tuple(p) for p in FIELD[:-1]]
    assert sim.param("FENCE_TYPE") == 4 and sim.param("FENCE_ENABLE") == 1
    wait_until(
        lambda: not sim.armed and distance_m(sim.position(), vehicle.depot) < 2.5,
        timeout=60,
        what="the rover parked at its depot",
        details=workers.logs,
    )
    assert sim.position().alt == 0.0


def test_an_rv_worker_dives_a_sub_over_mavlink_through_a_vv(
    workers, sims, tmp_path: Path, monkeypatch
) -> None:
    points = [(48.1128, 12.8605, -5), (48.1122, 12.8612, -5)]
    sub = {
        "name": "Sub",
        "kind": "underwater",
        "min_altitude_m": -30,
        "max_altitude_m": 0,
        "max_speed_mps": 10,
        "climb_rate_mps": 1,
        "dive_rate_mps": 0.5,
    }
    load(_scenario(sub, points, tmp_path), tmp_path, monkeypatch)
    vehicle = Vehicle.objects.get(name="Sub")
    assert vehicle.kind == "underwater" and vehicle.dive_rate_mps == 0.5
    sims.append(sim := _mavsim(vehicle, "sub"))

    vv = _serve_to_the_end(workers, vehicle)
    _assert_every_reading_where_asked(vv, vehicle, len(points))
    for task in vv.tasks.all():
        assert task.alt == -5 and task.readings[0]["position"]["alt"] == pytest.approx(-5, abs=2)
    wait_until(
        lambda: not sim.armed and sim.position().alt == 0.0,
        timeout=60,
        what="the sub home at the surface",
        details=workers.logs,
    )
    assert distance_m(sim.position(), vehicle.depot) < 2.5
