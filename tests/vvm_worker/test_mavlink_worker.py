"""RV workers flying real MAVLink links: the worker's MAVLink driver against a MAVLink-speaking
simulated copter (MavSim) on loopback, the rest of the platform as in production."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from fleet.geo import Position, distance_m
from fleet.mavlink import MavSim
from fleet.mavlink.sim.companion import FieldSensors
from fleet.models import Driver, Flight, FlightEnd, Vehicle, VehicleStatus
from fleet.simulation.vehicle import VehicleSpec
from missions.models import JournalEntry, Migration, Task, TaskStatus, VirtualVehicle, VVStatus
from tests.conftest import SCENARIOS
from tests.fleet.mavlink.conftest import free_udp_port
from tests.polling import wait_until
from tests.vvm_worker.test_distributed import KEYS, all_ended, load
from vvm_worker.executor import time_scale
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vehicle_set_status

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

SPEED = 25.0  # the workers' time acceleration (tests/live.py), the simulators' too


def _vv1_only(vehicles: list[dict]) -> dict:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    data["vehicles"] = vehicles
    data["vvs"] = [vv for vv in data["vvs"] if vv["name"] == "VV 1"]
    return data


def _mavlink(vehicle: Vehicle, **options: Any) -> MavSim:
    """Make ``vehicle`` a MAVLink vehicle and start its copter, which its worker will reach."""
    port = free_udp_port()
    vehicle.driver, vehicle.driver_url = Driver.MAVLINK, f"udpout:127.0.0.1:{port}"
    vehicle.save(update_fields=["driver", "driver_url"])
    spec = VehicleSpec(
        max_speed_mps=vehicle.max_speed_mps,
        climb_rate_mps=vehicle.climb_rate_mps,
        battery_s=vehicle.battery_s,
    )
    return MavSim(
        f"udpin:127.0.0.1:{port}",
        spec=spec,
        depot=vehicle.depot,
        speed=SPEED,
        name=vehicle.name,
        **options,
    ).start()


@pytest.fixture
def copters():
    started: list[MavSim] = []
    yield started
    for sim in started:
        sim.stop()


def test_an_rv_worker_flies_the_papers_vv_1_over_mavlink(
    workers, copters, tmp_path: Path, monkeypatch
) -> None:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    load(_vv1_only(data["vehicles"]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    copters.append(sim := _mavlink(heli))
    # The worker's time acceleration is for simulated vehicles only (issue 25): instant here,
    # and the copter (25 times real time) still flies, arrives and lands as it reports.
    workers.env["CPCC_SIM_SPEED"] = "0"
    workers.env["CPCC_STANDBY_S"] = "1"  # real seconds in the air before it lands
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_until(all_ended, timeout=180, what="VV 1 to end", details=workers.logs)
    vv = VirtualVehicle.objects.get()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert set(vv.storage.values_list("key", flat=True)) == KEYS
    done = list(vv.tasks.filter(status=TaskStatus.DONE))
    assert len(done) == 4 and all(t.vehicle == heli for t in done)
    for task in done:  # read where the copter was: within the task's tolerance
        where = task.readings[0]["position"]
        here = Position(where["lat"], where["lng"], where["alt"])
        assert distance_m(here, task.position) <= task.tolerance_m
    # The geofence the copter received: the operation area, and the ceiling above its home.
    (polygon,) = sim.fence_polygons()
    ring = [tuple(p) for p in heli.area[:-1]]
    assert [(round(a, 6), round(b, 6)) for a, b in polygon] == ring
    assert sim.param("FENCE_ALT_MAX") == pytest.approx(heli.max_altitude_m - heli.depot_alt)
    assert sim.param("FENCE_ENABLE") == 1
    wait_until(lambda: sim.on_ground, timeout=60, what="the copter to land at its depot")
    # Its flight (issue 58), closed with the landing's report: the copter's telemetry.
    wait_until(
        lambda: Flight.objects.filter(vehicle=heli, ended__isnull=False).exists(),
        timeout=30,
        what="the flight closed",
        details=workers.logs,
    )
    flight = Flight.objects.get(vehicle=heli)
    heli.refresh_from_db()
    assert (flight.ended_how, flight.tasks_served) == (FlightEnd.LANDED_HOME, 4)
    assert [c["id"] for c in flight.customers] == [vv.customer_id]
    assert [v["id"] for v in flight.vvs] == [str(vv.pk)]
    # Armed to disarmed, as the autopilot flew it: within its take-off and landing's reports.
    assert 0.0 < flight.duration_s <= flight.ended_s - flight.started_s + 1.0
    assert flight.distance_m == pytest.approx(heli.distance_m)  # its one flight
    assert flight.distance_m >= sum(  # at least straight from task to task
        distance_m(a.position, b.position)
        for a, b in itertools.pairwise(sorted(done, key=lambda t: t.done_s))
    )
    assert 5.0 < flight.max_alt_m <= heli.max_altitude_m
    # SYS_STATUS's battery_remaining (no endurance configured: the autopilot's word only).
    assert flight.battery_start_pct is not None and flight.battery_end_pct is not None
    assert 0.0 < flight.battery_end_pct <= flight.battery_start_pct <= 100.0
    # Its MAVLink stream, kept as a .tlog through the storage: what a ground station reads.
    wait_until(
        lambda: bool(Flight.objects.get(pk=flight.pk).log),
        timeout=30,
        what="the flight's log",
        details=workers.logs,
    )
    flight.refresh_from_db()
    log = mavutil.mavlink_connection(flight.log.path)
    track = []
    while (message := log.recv_match(type="GLOBAL_POSITION_INT")) is not None:
        track.append(
            (message._timestamp, message.lat / 1e7, message.lon / 1e7, message.relative_alt / 1000)
        )
    assert len(track) > 20 and all(a[0] <= b[0] for a, b in itertools.pairwise(track))
    depot = heli.depot
    assert distance_m(Position(*track[-1][1:3], 0.0), depot.with_alt(0.0)) <= 5.0
    assert max(alt for *_, alt in track) == pytest.approx(flight.max_alt_m, abs=3.0)
    for task in done:  # it passed over every task it served
        assert (
            min(distance_m(Position(lat, lng, alt), task.position) for _, lat, lng, alt in track)
            <= task.tolerance_m + 2.0
        )


def test_a_link_cut_in_flight_hands_the_vv_to_another_rv_and_nothing_is_read_twice(
    workers, copters, tmp_path: Path, monkeypatch
) -> None:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    slow = dict(data["vehicles"][0], name="Heli Two", depot=[48.1100, 12.8650, 0], max_speed_mps=4)
    load(_vv1_only([data["vehicles"][0], slow]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    copters.append(sim := _mavlink(heli))
    workers.env["CPCC_MAVLINK_LINK_TIMEOUT_S"] = "1"
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    wait_until(
        lambda: Task.objects.filter(status=TaskStatus.DONE, vehicle=heli).exists(),
        timeout=120,
        what="a task done by the MAVLink RV",
        details=workers.logs,
    )
    sim.cut_link()  # the radio dies in flight
    wait_until(
        lambda: Vehicle.objects.get(pk=heli.pk).status == VehicleStatus.OFFLINE,
        timeout=30,
        what="the RV offline",
        details=workers.logs,
    )
    assert Vehicle.objects.get(pk=heli.pk).status_reason == "link lost"
    wait_until(all_ended, timeout=180, what="VV 1 to end", details=workers.logs)
    vv = VirtualVehicle.objects.get()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert set(vv.storage.values_list("key", flat=True)) == KEYS
    assert vv.tasks.count() == 4 and vv.tasks.filter(status=TaskStatus.DONE).count() == 4
    assert JournalEntry.objects.filter(vv=vv).count() == 4, "every reading exactly once"
    assert vv.tasks.filter(vehicle__name="Heli Two", status=TaskStatus.DONE).exists()
    assert Migration.objects.filter(vv=vv, from_name="Heli One", to_name="Heli Two").exists() or (
        Migration.objects.filter(vv=vv, from_name="Heli One", to_kind="gs").exists()
    )
    # The link comes back: the RV returns to service by itself.
    sim.restore_link()
    wait_until(
        lambda: Vehicle.objects.get(pk=heli.pk).status == VehicleStatus.ACTIVE,
        timeout=30,
        what="the RV back in service",
        details=workers.logs,
    )
    assert Vehicle.objects.get(pk=heli.pk).status_reason == "link back"


def test_maintenance_set_while_the_link_is_down_survives_the_links_return(
    workers, copters, tmp_path: Path, monkeypatch
) -> None:
    """Issue 25: the link is the vehicle's health; maintenance is a person's decision."""
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    load(_vv1_only(data["vehicles"]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    copters.append(sim := _mavlink(heli))
    workers.env["CPCC_MAVLINK_LINK_TIMEOUT_S"] = "1"
    workers.env["CPCC_LOG_LEVEL"] = "INFO"
    workers.start("rvworker", "Heli One")
    wait_until(
        lambda: any("rv worker started" in p.read_text() for p in tmp_path.glob("*.log")),
        timeout=60,
        what="the RV worker",
        details=workers.logs,
    )
    sim.cut_link()
    wait_until(
        lambda: Vehicle.objects.get(pk=heli.pk).status == VehicleStatus.OFFLINE,
        timeout=30,
        what="the RV offline",
        details=workers.logs,
    )
    vehicle_set_status(
        vehicle=heli,
        status=VehicleStatus.MAINTENANCE,
        vvm=platform_vvm(),
        reason="propeller check",
    )
    sim.restore_link()
    wait_until(
        lambda: any("Heli One: link back" in p.read_text() for p in tmp_path.glob("*.log")),
        timeout=30,
        what="the worker to see the link back",
        details=workers.logs,
    )
    heli.refresh_from_db()
    assert (heli.status, heli.status_reason) == (VehicleStatus.MAINTENANCE, "propeller check")


def test_a_vv_on_a_mavlink_rv_gets_the_readings_of_the_vehicles_own_sensors(
    workers, copters, tmp_path: Path, monkeypatch
) -> None:
    """Issue 24: CO2 from the companion computer (NAMED_VALUE_FLOAT), the temperature from the
    autopilot (SCALED_PRESSURE), the picture through the camera protocol. The copter's world
    measures what the platform's simulated field never gives."""
    measured = {"co2": 1234.5, "nox": 42.25, "temperature": 21.5, "pressure": 1000.25}
    monkeypatch.setattr(FieldSensors, "value", lambda self, quantity, *_: measured[quantity])
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    load(_vv1_only(data["vehicles"]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    heli.sensor_sources = {
        "CO2": {"source": "named_value", "name": "CO2"},
        "Thermometer": {"source": "telemetry"},
        "Camera 640x480": {"source": "camera", "timeout_s": 10},
    }
    heli.save(update_fields=["sensor_sources"])
    copters.append(_mavlink(heli, payload=True))
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_until(all_ended, timeout=180, what="VV 1 to end", details=workers.logs)
    vv = VirtualVehicle.objects.get()
    assert vv.status == VVStatus.FINISHED, vv.error
    stored = {d.key: d.value for d in vv.storage.all()}
    assert set(stored) == KEYS
    tasks = list(vv.tasks.filter(status=TaskStatus.DONE).order_by("q"))
    assert len(tasks) == 4
    for n, task in enumerate(tasks):
        co2, temperature, picture = (stored[f"p{n}.{k}"] for k in range(3))
        assert (co2["sensor"], co2["value"], co2["unit"]) == ("CO2", 1234.5, "ppm")
        assert (temperature["value"], temperature["unit"]) == (21.5, "°C")
        assert (picture["width"], picture["height"], picture["format"]) == (640, 480, "png")
        assert picture["image"].startswith("readings/") and picture["image"].endswith(".png")
        # Where the vehicle was when it took them: at the task, within its tolerance.
        for reading in (co2, temperature, picture):
            where = reading["position"]
            here = Position(where["lat"], where["lng"], where["alt"])
            assert distance_m(here, task.position) <= task.tolerance_m + 0.5


def test_a_stopped_workers_drone_returns_home_by_the_autopilots_failsafe(
    workers, copters, tmp_path: Path, monkeypatch
) -> None:
    """Issue 25: the worker turns the GCS failsafe on; when it stops, the autopilot hears no
    ground station and flies home by itself."""
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    load(_vv1_only(data["vehicles"]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    copters.append(sim := _mavlink(heli))
    workers.env["CPCC_GCS_FAILSAFE_S"] = "2"
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_until(
        lambda: sim.param("FS_GCS_ENABLE") == 1 and sim.param("FS_GCS_TIMEOUT") == 2,
        timeout=60,
        what="the GCS failsafe turned on",
        details=workers.logs,
    )
    wait_until(
        lambda: not sim.on_ground and distance_m(sim.position(), heli.depot) > 30,
        timeout=120,
        what="the copter on its way",
        details=workers.logs,
    )
    assert workers.terminate("Heli One") == 0
    wait_until(lambda: sim.mode == "RTL", timeout=30, what="the failsafe's RTL")
    assert "GCS Failsafe" in sim.texts_sent()
    wait_until(lambda: sim.on_ground, timeout=120, what="the copter landed")
    assert distance_m(sim.position(), heli.depot) < 2.0


def test_a_low_battery_keeps_the_rv_home_until_telemetry_shows_it_charged_and_a_swap_counts(
    workers, copters, tmp_path: Path, monkeypatch
) -> None:
    """Issue 25: the battery from the vehicle, not from a timer. The RV whose battery is too
    low for the task stays `charging` (no loop back to service after CPCC_RECHARGE_S) until
    the autopilot reports a charged battery; a swap is seen at once and the VV goes on."""
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    load(_vv1_only([dict(data["vehicles"][0], battery_s=400)]), tmp_path, monkeypatch)
    heli = Vehicle.objects.get(name="Heli One")
    copters.append(sim := _mavlink(heli, battery=0.25))
    workers.env["CPCC_RECHARGE_S"] = "1"  # a timer would put it back into service at once
    workers.env["CPCC_LOG_LEVEL"] = "INFO"
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    log = tmp_path / "rvworker-Heli_One.log"
    wait_until(
        lambda: "waiting for a charged battery" in log.read_text(),
        timeout=60,
        what="the RV waiting for its battery",
        details=workers.logs,
    )
    heli.refresh_from_db()
    assert (heli.status, heli.status_reason) == (
        VehicleStatus.CHARGING,
        "battery too low for the next task",
    )
    assert sim.on_ground and not sim.armed
    sim.set_battery(1.0)  # swapped
    wait_until(all_ended, timeout=180, what="VV 1 to end", details=workers.logs)
    vv = VirtualVehicle.objects.get()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert log.read_text().count("battery too low for the next task: home to recharge") == 1, (
        "no loop"
    )
    assert Vehicle.objects.get(pk=heli.pk).status_reason == "charged"


def test_the_time_acceleration_is_for_simulated_vehicles_only() -> None:
    sim = Vehicle(driver=Driver.SIM)
    real = Vehicle(driver=Driver.MAVLINK)
    assert [time_scale(real, speed) for speed in (0.0, 1.0, 25.0)] == [1.0, 1.0, 1.0]
    assert [time_scale(sim, speed) for speed in (1.0, 25.0)] == [1.0, 25.0]
    assert time_scale(sim, 0.0) > 1e5  # instant flights
