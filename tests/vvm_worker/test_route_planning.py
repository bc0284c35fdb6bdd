"""The RV's control loop with the default planner: turning in flight, waiting in the middle."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from shapely.geometry import LineString, Polygon

from fleet.geo import offset
from missions.models import TrackPoint
from vvm_worker.scenario import load_scenario, parse_scenario
from vvm_worker.scenario_gen import GRID_ORIGIN, ONE_TASK, grid_scenario
from vvm_worker.simulation import Simulation


def one_task_vv(name: str, north_m: float, east_m: float, at_s: float) -> dict:
    p = offset(GRID_ORIGIN, north_m=north_m, east_m=east_m, up_m=30.0)
    return {
        "customer": "Customer 1",
        "name": name,
        "source": ONE_TASK % {"lat": p.lat, "lng": p.lng, "alt": p.alt},
        "submit_at_s": at_s,
    }


def done_at(summary: dict) -> dict[str, float]:
    return {vv["name"]: vv["tasks"][0]["done_s"] for vv in summary["vvs"]}


@pytest.mark.django_db
@pytest.mark.parametrize(("planner", "first"), [("latency", "Near"), ("nearest", "Far")])
def test_a_task_that_arrives_on_the_way_is_served_first_by_the_default_planner(
    planner: str, first: str
) -> None:
    # One RV in the middle of a 400 m cell. The far corner is asked for at 0 s; at 12 s, as
    # the RV sets off, a point 15 m from it. `latency` turns to it; `nearest` flies on.
    vvs = [one_task_vv("Far", 390, 390, 0.0), one_task_vv("Near", 205, 210, 12.0)]
    data = grid_scenario(rows=1, cols=1, cell_m=400, max_speed_mps=10.0, vvs=vvs)
    summary = Simulation(parse_scenario(data, base_dir=Path(".")), planner=planner).run()
    assert all(vv["status"] == "finished" for vv in summary["vvs"])
    done = done_at(summary)
    assert min(done, key=done.__getitem__) == first
    if planner == "latency":
        # Turning costs the far task a few seconds and saves the near one half a minute.
        assert done["Near"] < 20.0


@pytest.mark.django_db
def test_an_idle_rv_waits_in_the_middle_of_its_area_and_is_quicker_there() -> None:
    # The depot is the south-west corner; tasks come every 60 s at random-ish points. Waiting
    # in the air in the middle, the RV reaches each in less time than from the ground.
    data = grid_scenario(rows=1, cols=1, cell_m=400, max_speed_mps=10.0)
    corner = offset(GRID_ORIGIN, north_m=5, east_m=5)
    data["vehicles"][0]["depot"] = [corner.lat, corner.lng, 0]
    data["vvs"] = [
        one_task_vv(f"VV {k}", 100 + 37 * k % 200, 300 - 53 * k % 200, 60.0 * k) for k in range(6)
    ]
    waits = {}
    for seed, planner in enumerate(("latency", "nearest"), start=1):  # a seed each: new VV ids
        summary = Simulation(
            parse_scenario(data, base_dir=Path(".")), planner=planner, seed=seed
        ).run()
        waits[planner] = [
            vv["tasks"][0]["done_s"] - vv["tasks"][0]["requested_s"] for vv in summary["vvs"]
        ]
    # The first task starts from the depot either way; each later one from the middle.
    assert waits["latency"][0] == pytest.approx(waits["nearest"][0])
    assert all(a < b for a, b in zip(waits["latency"][1:], waits["nearest"][1:], strict=True))


NO_FLY = Path(__file__).resolve().parents[2] / "examples" / "scenarios" / "no-fly-zone.json"


def _flown(vv_name: str) -> LineString:
    track = TrackPoint.objects.filter(vv__name=vv_name).order_by("t_s", "id")
    return LineString([(p.lng, p.lat) for p in track])


@pytest.mark.django_db
@pytest.mark.parametrize("zoned", [True, False])
def test_simulate_flies_round_a_no_fly_zone_and_over_one_with_a_ceiling(zoned: bool) -> None:
    scenario = load_scenario(NO_FLY)
    substation = Polygon([(lng, lat) for lat, lng in scenario.no_fly_zones[0].area])
    if not zoned:  # the same run through the zones: the test would see it
        scenario = dataclasses.replace(scenario, no_fly_zones=())
    summary = Simulation(scenario).run()
    (vv,) = summary["vvs"]
    assert (vv["status"], vv["tasks_done"]) == ("finished", 5)  # the one above the stadium too
    assert sorted(vv["storage"]) == [f"co2.{n}" for n in range(5)]
    flown = _flown("Both sides")
    assert flown.intersects(substation) is not zoned
    distance = summary["vehicles"][0]["distance_m"]
    # Three times across, each time round the substation's end: 1,900 m straight, 2,200 round.
    assert (distance > 2050.0) is zoned
