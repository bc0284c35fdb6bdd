"""The example of issue 28 (examples/scenarios/lake-and-fields.json) does what it says: copters
over the fields and the lake, rovers on the fields, a boat and a submarine in the lake, and one
VV (examples/vv/air-land-water.js) that takes a reading in the air, on a field, on the lake and
5 m under it, migrating from one kind of vehicle to the next."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import Any

import pytest
from django.db import transaction
from django.test import override_settings
from shapely.geometry import Point, Polygon

from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER
from fleet.models import Vehicle
from tests.conftest import SCENARIOS
from vvm_worker.scenario import Scenario, load_scenario
from vvm_worker.simulation import Simulation

# The tests read the module's one run (``summary``), which the database setup serves.
pytestmark = pytest.mark.django_db

CROSSING = "Air, land and water"
# examples/vv/air-land-water.js: each leg's storage key, where it is (lat, lng, alt) and the
# kind of vehicle that alone can take its reading there.
LEGS = {
    "0.air": ((48.1125, 12.8590, 30.0), AERIAL),
    "1.land": ((48.1100, 12.8595, 0.0), GROUND),
    "2.surface": ((48.1124, 12.8642, 0.0), SURFACE),
    "3.underwater": ((48.1118, 12.8652, -5.0), UNDERWATER),
}
TOLERANCE_M = 2.0  # the program's tolerance
M_PER_DEG_LAT = 111_320.0
# The run's summary, and each vehicle's kind by name.
Run = tuple[dict[str, Any], dict[str, str]]


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario(SCENARIOS / "lake-and-fields.json")


@pytest.fixture(scope="module")
def run(
    scenario: Scenario,
    django_db_setup: None,
    django_db_blocker: Any,
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Run]:
    """The scenario simulated once for the module (as ``manage.py simulate --speed 0`` runs
    it), in a transaction rolled back at the end: its summary, and each vehicle's kind as its
    row in the database says."""
    media = tmp_path_factory.mktemp("example-kinds-media")
    with (
        django_db_blocker.unblock(),
        transaction.atomic(),
        override_settings(MEDIA_ROOT=media),
    ):
        summary = Simulation(scenario).run()
        kinds = dict(Vehicle.objects.values_list("name", "kind"))
        yield summary, kinds
        transaction.set_rollback(True)


def vv(summary: dict[str, Any], name: str) -> dict[str, Any]:
    (found,) = [v for v in summary["vvs"] if v["name"] == name]
    return dict(found)


def area_of(scenario: Scenario, vehicle: str) -> Polygon:
    (spec,) = [v for v in scenario.vehicles if v.name == vehicle]
    return Polygon([(lng, lat) for lat, lng in spec.area])


def test_every_vv_of_the_scenario_finishes_with_every_task_done(run: Run) -> None:
    summary, _ = run
    assert {v["name"]: (v["status"], v["error"]) for v in summary["vvs"]} == {
        "VV 1": ("finished", None),
        "Soil survey": ("finished", None),
        "Lake profile": ("finished", None),
        CROSSING: ("finished", None),
    }
    for done in summary["vvs"]:
        assert done["tasks"] and all(t["status"] == "done" for t in done["tasks"]), done["name"]


def test_the_scenarios_vehicles_are_of_every_kind(run: Run) -> None:
    _, kinds = run
    assert kinds == {
        "Copter West": AERIAL,
        "Copter East": AERIAL,
        "Rover West": GROUND,
        "Rover East": GROUND,
        "Boat": SURFACE,
        "Sub": UNDERWATER,
    }


def test_the_crossing_vv_stores_one_reading_per_leg_where_it_was_taken(run: Run) -> None:
    summary, _ = run
    storage = vv(summary, CROSSING)["storage"]
    assert sorted(storage) == sorted(LEGS)
    for key, ((lat, lng, alt), _) in LEGS.items():
        reading = storage[key]
        at = reading["position"]
        north_m = (at["lat"] - lat) * M_PER_DEG_LAT
        east_m = (at["lng"] - lng) * M_PER_DEG_LAT * 0.668  # cos(48.11°)
        assert (north_m**2 + east_m**2 + (at["alt"] - alt) ** 2) ** 0.5 <= TOLERANCE_M, key
        assert isinstance(reading["value"], float), key
    # Under water the reading was taken below the surface, and its depth gauge says so.
    under = storage["3.underwater"]
    assert under["sensor"] == "Depth gauge" and under["position"]["alt"] < 0
    assert under["value"] == pytest.approx(-5.0, abs=1.0)
    assert storage["1.land"]["sensor"] == "Soil temperature"
    assert storage["2.surface"]["sensor"] == "Water temperature"


def test_the_crossing_vv_is_carried_by_a_vehicle_of_each_kind_in_turn(run: Run) -> None:
    summary, kinds = run
    tasks = vv(summary, CROSSING)["tasks"]
    served = [(tuple(t["position"]), kinds[t["vehicle"]]) for t in tasks]
    assert served == [(at, kind) for at, kind in LEGS.values()]
    # From the ground station to a vehicle of each kind in the order of the legs, and back.
    hops = [(m["from"], m["to"]) for m in summary["migrations"] if m["vv"] == CROSSING]
    assert hops[0][0] == hops[-1][1] == "GS Shore"
    assert [kinds[to] for _, to in hops[:-1]] == [AERIAL, GROUND, SURFACE, UNDERWATER]
    assert all(a == b for (_, a), (b, _) in itertools.pairwise(hops))


def test_each_kind_serves_tasks_only_where_it_can_go(run: Run, scenario: Scenario) -> None:
    summary, kinds = run
    for name in ("VV 1", "Soil survey", "Lake profile", CROSSING):
        for task in vv(summary, name)["tasks"]:
            lat, lng, alt = task["position"]
            vehicle = task["vehicle"]
            assert area_of(scenario, vehicle).covers(Point(lng, lat)), (name, task)
            kind = kinds[vehicle]
            if alt < 0:
                assert kind == UNDERWATER, (name, task)
            elif kind in (GROUND, SURFACE):
                assert alt == 0, (name, task)
    # The lake profile's surface readings are the boat's, its depths the submarine's.
    profile = vv(summary, "Lake profile")
    assert [kinds[t["vehicle"]] for t in profile["tasks"]] == [SURFACE] * 2 + [UNDERWATER] * 3
    depths = [profile["storage"][f"depth.{k}"] for k in range(3)]
    assert depths == pytest.approx([-2.0, -10.0, -20.0], abs=1.0)
    # The rovers keep to their fields: neither drives into the lake.
    lake = area_of(scenario, "Boat")
    for rover in ("Rover West", "Rover East"):
        assert not area_of(scenario, rover).intersects(lake)
