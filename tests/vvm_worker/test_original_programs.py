"""Programs written for the original CPCC implementation run unchanged on grids of RVs."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.geo import Position, distance_m, offset
from vvm_worker.scenario import parse_scenario
from vvm_worker.scenario_gen import grid_box, grid_scenario, original_style_program
from vvm_worker.simulation import Simulation

ORIGIN = Position(48.1100, 12.8600, 0.0)


def run(data: dict) -> dict:
    return Simulation(parse_scenario(data, base_dir=Path(".")), planner="nearest").run()


def rv_to_rv(summary: dict, vv: str) -> list[dict]:
    rvs = {v["name"] for v in summary["vehicles"]}
    return [
        m for m in summary["migrations"] if m["vv"] == vv and m["from"] in rvs and m["to"] in rvs
    ]


@pytest.mark.django_db
def test_four_copies_of_a_50_task_program_finish_on_a_3x3_grid_of_50_m_cells() -> None:
    box = grid_box(rows=3, cols=3, cell_m=50)
    source = original_style_program(box=box, tasks=50)
    data = grid_scenario(rows=3, cols=3, cell_m=50, customers=2)
    data["vvs"] = [
        {"customer": "Customer 1", "name": "demo", "source": source, "copies": 2},
        {"customer": "Customer 2", "name": "demo", "source": source, "copies": 2},
    ]
    summary = run(data)
    assert len(summary["vvs"]) == 4
    for vv in summary["vvs"]:
        assert vv["status"] == "finished", vv["error"]
        assert vv["tasks_done"] == 50
        assert sorted(vv["storage"]) == sorted(f"pos-{k}" for k in range(50))
        for k, task in enumerate(vv["tasks"]):
            reading = vv["storage"][f"pos-{k}"]
            assert reading["sensor"] == "GPS"
            fix = Position(reading["lat"], reading["lng"], reading["alt"])
            assert distance_m(fix, Position(*task["position"])) < 4 + 5  # tolerance + GPS error
        # Random points over nine cells: the VV keeps moving between RVs.
        assert len(rv_to_rv(summary, vv["name"])) > 10
    # Each copy has its own Math.random seed, so the copies visit different points.
    firsts = {tuple(v["tasks"][0]["position"]) for v in summary["vvs"]}
    assert len(firsts) == 4
    assert sum(v["tasks_done"] for v in summary["vehicles"]) == 200


@pytest.mark.django_db
def test_a_200_task_program_finishes_on_a_2x2_grid_of_200_m_cells() -> None:
    box = grid_box(rows=2, cols=2, cell_m=200)
    data = grid_scenario(rows=2, cols=2, cell_m=200)
    data["vvs"] = [
        {
            "customer": "Customer 1",
            "name": "survey",
            "source": original_style_program(box=box, tasks=200),
        }
    ]
    summary = run(data)
    (vv,) = summary["vvs"]
    assert vv["status"] == "finished", vv["error"]
    assert len(vv["storage"]) == 200
    assert {v["name"] for v in summary["vehicles"] if v["tasks_done"] > 0} == {
        "RV 0-0",
        "RV 0-1",
        "RV 1-0",
        "RV 1-1",
    }


STATEFUL = """
var gps = VV.sensor.get('GPS');
var points = %s;
function counter() { var n = 0; return function () { n += 1; return n; }; }
var next = counter();
var seen = [];
for (var i = 0; i < points.length; i++) {
  var r = Math.random();
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(points[i][0], points[i][1], 30),
                   tolerance: 2, sensors: [gps]}, function (d) {
    seen.push({i: i, count: next(), r: r, again: Math.random()});
  });
}
VV.storage.store('seen', seen);
VV.storage.store('last', Math.random());
"""


@pytest.mark.django_db
def test_math_random_and_closures_are_the_same_after_five_migrations() -> None:
    # Six points in six different cells of a 2x3 grid: five RV-to-RV migrations.
    cells = [(0, 0), (0, 1), (0, 2), (1, 2), (1, 1), (1, 0)]
    points = [offset(ORIGIN, north_m=(r + 0.5) * 100, east_m=(c + 0.5) * 100) for r, c in cells]
    source = STATEFUL % [[p.lat, p.lng] for p in points]
    moved = grid_scenario(rows=2, cols=3, cell_m=100)
    moved["vvs"] = [{"customer": "Customer 1", "name": "stateful", "source": source}]
    # The same program served by one RV whose area covers everything: it never moves.
    still = grid_scenario(rows=1, cols=1, cell_m=300)
    still["vvs"] = [{"customer": "Customer 1", "name": "stateful", "source": source}]

    moved_summary = run(moved)
    (vv_moved,) = moved_summary["vvs"]
    assert vv_moved["status"] == "finished", vv_moved["error"]
    assert len(rv_to_rv(moved_summary, "stateful")) == 5

    # A fresh database for the second run, as in two runs of `simulate`.
    from missions.models import VirtualVehicle

    VirtualVehicle.objects.all().delete()
    still_summary = run(still)
    (vv_still,) = still_summary["vvs"]
    assert rv_to_rv(still_summary, "stateful") == []
    assert vv_moved["storage"] == vv_still["storage"]
    assert [s["count"] for s in vv_moved["storage"]["seen"]] == [1, 2, 3, 4, 5, 6]
    assert [s["i"] for s in vv_moved["storage"]["seen"]] == [0, 1, 2, 3, 4, 5]
