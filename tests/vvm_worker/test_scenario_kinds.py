"""Vehicle kinds in scenario files: `kind`, `dive_rate_mps`, `turn_rate_dps` of a vehicle and
`kinds` of an SDC entry, checked against the kind's limits, and loaded into the database."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import pytest

from fleet.models import SensorType, Vehicle
from missions.models import Task, VVStatus
from tests.factories import VehicleFactory
from vvm_worker.scenario import Scenario, ScenarioError, parse_scenario
from vvm_worker.services import vv_submit
from vvm_worker.services.dry_run import fleet_copy
from vvm_worker.services.scenarios import scenario_apply

SQUARE = [[48.0, 12.0], [48.0, 12.01], [48.01, 12.01], [48.01, 12.0], [48.0, 12.0]]


def vehicle(name: str, **extra: Any) -> dict[str, Any]:
    return {
        "name": name,
        "depot": [48.005, 12.005, 0],
        "area": copy.deepcopy(SQUARE),
        "max_speed_mps": 5,
        "sensors": ["Thermometer"],
        **extra,
    }


def document(*vehicles: dict[str, Any], sensors: list[dict[str, Any]] | None = None) -> dict:
    doc: dict[str, Any] = {
        "name": "Kinds",
        "ground_stations": [{"name": "GS Base", "position": [48.0, 12.0, 0]}],
        "vehicles": list(vehicles),
        "customers": [{"name": "Customer A", "max_parallel_vvs": 1}],
        "vvs": [],
    }
    if sensors is not None:
        doc["sensors"] = sensors
    return doc


def parse(doc: dict[str, Any]) -> Scenario:
    return parse_scenario(doc, base_dir=Path("/nonexistent"))


def refused(doc: dict[str, Any], pattern: str) -> ScenarioError:
    with pytest.raises(ScenarioError) as caught:
        parse(doc)
    assert re.search(pattern, str(caught.value)), str(caught.value)
    return caught.value


COPTER = vehicle("Copter", min_altitude_m=0, max_altitude_m=120)
SONAR = {"name": "Sonar", "kind": "scalar", "unit": "m", "kinds": ["underwater", "surface"]}


def test_a_vehicle_without_a_kind_is_aerial_as_before() -> None:
    (spec,) = parse(document(COPTER)).vehicles
    assert (spec.kind, spec.dive_rate_mps, spec.turn_rate_dps) == ("aerial", None, None)
    assert (spec.min_altitude_m, spec.max_altitude_m) == (0.0, 120.0)


@pytest.mark.parametrize("kind", ["ground", "surface"])
def test_a_ground_or_surface_vehicle_stays_at_0_m_and_may_turn_at_its_own_rate(kind: str) -> None:
    (spec,) = parse(document(vehicle("Rover", kind=kind, turn_rate_dps=45))).vehicles
    assert (spec.kind, spec.min_altitude_m, spec.max_altitude_m) == (kind, 0.0, 0.0)
    assert spec.turn_rate_dps == 45.0


def test_an_underwater_vehicle_dives_to_its_min_altitude_at_its_dive_rate() -> None:
    sub = vehicle("Sub", kind="underwater", min_altitude_m=-80, dive_rate_mps=0.5)
    (spec,) = parse(document(sub)).vehicles
    assert (spec.min_altitude_m, spec.max_altitude_m, spec.dive_rate_mps) == (-80.0, 0.0, 0.5)


@pytest.mark.parametrize(
    ("extra", "pattern"),
    [
        ({"kind": "hovercraft"}, r"^vehicles\[0\]\.kind: unknown vehicle kind 'hovercraft' \(one "
         r"of: aerial, ground, surface, underwater\)"),
        ({"kind": "ground", "max_altitude_m": 30}, r"^vehicles\[0\]\.max_altitude_m: a ground "
         r"vehicle goes no higher than 0 m: it moves in the plane and never climbs, got 30"),
        ({"kind": "surface", "max_speed_mps": 25}, r"^vehicles\[0\]\.max_speed_mps: a surface "
         r"vehicle moves at 20 m/s at most, got 25"),
        ({"kind": "underwater"}, r"^vehicles\[0\]: missing required key 'min_altitude_m' \(how "
         r"deep it goes"),
        ({"kind": "underwater", "min_altitude_m": 0}, r"^vehicles\[0\]\.min_altitude_m: an "
         r"underwater vehicle dives: .* must be below 0"),
        ({"kind": "underwater", "min_altitude_m": -400}, r"^vehicles\[0\]\.min_altitude_m: an "
         r"underwater vehicle goes no lower than -300 m \(below 0 is depth\), got -400"),
        ({"kind": "underwater", "min_altitude_m": -5, "max_altitude_m": -10},
         r"^vehicles\[0\]\.min_altitude_m: min_altitude_m \(-5\) is above max_altitude_m"),
        ({"min_altitude_m": -5, "max_altitude_m": 50},
         r"^vehicles\[0\]\.min_altitude_m: must not be negative, got -5"),
        ({"max_altitude_m": 50}, r"^vehicles\[0\]: missing required key 'min_altitude_m'$"),
        ({"min_altitude_m": 0, "max_altitude_m": 50, "dive_rate_mps": 1},
         r"^vehicles\[0\]\.dive_rate_mps: only underwater vehicles have a dive_rate_mps; this "
         r"one is aerial"),
        ({"kind": "underwater", "min_altitude_m": -5, "turn_rate_dps": 30},
         r"^vehicles\[0\]\.turn_rate_dps: only ground and surface vehicles have a "
         r"turn_rate_dps; this one is underwater"),
        ({"kind": "ground", "turn_rate_dps": 0}, r"^vehicles\[0\]\.turn_rate_dps: must be "
         r"greater than 0, got 0"),
        ({"kind": "underwater", "min_altitude_m": -5, "dive_rate_mps": "fast"},
         r"^vehicles\[0\]\.dive_rate_mps: must be a number, got a string"),
    ],
)  # fmt: skip
def test_a_vehicle_beyond_its_kind_is_refused_naming_the_field(
    extra: dict[str, Any], pattern: str
) -> None:
    refused(document(vehicle("Rover", **extra)), pattern)


def test_an_added_vehicle_is_checked_like_the_others() -> None:
    doc = document(COPTER)
    doc["events"] = [{"at_s": 10, "add_vehicle": vehicle("Rover", kind="ground", max_altitude_m=5)}]
    refused(doc, r"^events\[0\]\.add_vehicle\.max_altitude_m: a ground vehicle goes no higher")


def test_an_sdc_entry_names_the_kinds_that_carry_it() -> None:
    scenario = parse(document(COPTER, sensors=[SONAR]))
    assert scenario.sensors[0].kinds == ("underwater", "surface")
    refused(
        document(COPTER, sensors=[{**SONAR, "kinds": ["underwater", "spaceship"]}]),
        r"^sensors\[0\]\.kinds\[1\]: unknown vehicle kind 'spaceship'",
    )
    refused(
        document(COPTER, sensors=[{**SONAR, "kinds": "underwater"}]),
        r"^sensors\[0\]\.kinds: must be an array, got a string",
    )


@pytest.mark.django_db
def test_kinds_round_trip_into_the_fleet_and_the_catalog() -> None:
    sub = vehicle(
        "Sub", kind="underwater", min_altitude_m=-80, dive_rate_mps=0.5, sensors=["Sonar"]
    )
    boat = vehicle("Boat", kind="surface", turn_rate_dps=20, sensors=["Sonar", "Thermometer"])
    scenario = parse(document(COPTER, sub, boat, sensors=[SONAR]))
    scenario_apply(scenario=scenario, logins=False)
    rows = {v.name: v for v in Vehicle.objects.all()}
    assert (rows["Copter"].kind, rows["Copter"].dive_rate_mps) == ("aerial", None)
    assert (rows["Sub"].kind, rows["Sub"].min_altitude_m, rows["Sub"].max_altitude_m) == (
        "underwater",
        -80.0,
        0.0,
    )
    assert rows["Sub"].dive_rate_mps == 0.5
    assert (rows["Boat"].kind, rows["Boat"].turn_rate_dps) == ("surface", 20.0)
    assert sorted(s.name for s in rows["Boat"].sensors.all()) == ["Sonar", "Thermometer"]
    assert SensorType.objects.get(name="Sonar").kinds == ["underwater", "surface"]
    for row in rows.values():
        row.full_clean()  # what the scenario loaded, the model accepts


@pytest.mark.django_db
def test_a_vehicle_whose_kind_cannot_carry_a_sensor_is_refused_naming_both() -> None:
    rover = vehicle("Rover", kind="ground", sensors=["Thermometer", "Sonar"])
    scenario = parse(document(COPTER, rover, sensors=[SONAR]))
    with pytest.raises(ScenarioError) as caught:
        scenario_apply(scenario=scenario, logins=False)
    assert str(caught.value) == (
        "vehicles[1].sensors[1]: vehicle 'Rover' is ground: it cannot carry SDC entry 'Sonar' "
        "(carried by underwater, surface vehicles only)"
    )
    assert not Vehicle.objects.exists()


@pytest.mark.django_db
def test_an_sdc_entry_of_the_database_limits_the_kinds_too() -> None:
    SensorType.objects.create(name="Depth gauge", kind="scalar", unit="m", kinds=["underwater"])
    scenario = parse(document(vehicle("Boat", kind="surface", sensors=["Depth gauge"])))
    with pytest.raises(ScenarioError, match=r"^vehicles\[0\]\.sensors\[0\]: vehicle 'Boat' is "):
        scenario_apply(scenario=scenario, logins=False)


@pytest.mark.django_db
def test_a_dry_runs_copy_of_the_fleet_keeps_each_vehicles_kind(ground_station) -> None:
    sonar = SensorType.objects.create(name="Sonar", kind="scalar", unit="m", kinds=["underwater"])
    sub = VehicleFactory(
        name="Sub One",
        kind="underwater",
        min_altitude_m=-40,
        max_altitude_m=0,
        max_speed_mps=2,
        dive_rate_mps=0.5,
        sensors=[],
    )
    sub.sensors.set([sonar])
    VehicleFactory(name="Heli One", dive_rate_mps=2.0)  # a rate its kind does not have
    scenario = parse(fleet_copy(name="survey", program="VV.log(1);"))
    copied = {v.kind: v for v in scenario.vehicles}
    assert (copied["underwater"].min_altitude_m, copied["underwater"].dive_rate_mps) == (-40, 0.5)
    assert copied["aerial"].dive_rate_mps is None
    assert {s.name: s.kinds for s in scenario.sensors}["Sonar"] == ("underwater",)


# --- end to end: a VV asks for a task below the surface ----------------------------------------

DEPTH_PROGRAM = """
var t = VV.sensor.get('Thermometer');
try {
  var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, -5),
                           tolerance: 2, sensors: [t]});
  VV.storage.store('reading', d[0]);
} catch (e) {
  VV.storage.store('refused', e.name + ': ' + e.message);
}
"""


def run_depth_vv(platform: Any, customer: Any) -> dict[str, Any]:
    vv = vv_submit(customer=customer, name="Depth", program=DEPTH_PROGRAM, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    return {item.key: item for item in vv.storage.all()}


def test_a_task_below_the_surface_is_served_by_the_underwater_vehicle(
    platform, ground_station, customer_a
) -> None:
    heli = VehicleFactory(name="Heli One", sensors=["Thermometer"])
    sub = VehicleFactory(
        name="Sub One",
        kind="underwater",
        min_altitude_m=-40,
        max_altitude_m=0,
        max_speed_mps=2,
        sensors=["Thermometer"],
    )
    for vehicle in (heli, sub):
        platform.add_vehicle_loop(vehicle)
    stored = run_depth_vv(platform, customer_a)
    assert set(stored) == {"reading"}
    assert Task.objects.get().vehicle == sub


def test_a_task_below_the_surface_without_an_underwater_vehicle_is_refused_in_words(
    platform, ground_station, customer_a
) -> None:
    platform.add_vehicle_loop(VehicleFactory(name="Heli One", sensors=["Thermometer"]))
    stored = run_depth_vv(platform, customer_a)
    refused = str(stored["refused"].value)
    assert refused.startswith("TaskRejectedError: ")
    assert "the task is 5 m below the surface: no underwater vehicle covers it" in refused
    assert "Heli" not in refused
