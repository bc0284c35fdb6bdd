"""Generated scenarios: a grid of square cells with one RV each, and original-style VV programs.

Pure Python (no Django). The scenarios follow the contract of DESIGN.md section 5, so they run
through ``parse_scenario`` and ``simulate`` like a file would.
"""

from __future__ import annotations

import random
from typing import Any

from fleet.geo import Position, offset

GPS_ONLY = ["GPS"]
# The south-west corner of generated grids: next to the paper's field.
GRID_ORIGIN = Position(48.1100, 12.8600, 0.0)


def grid_scenario(
    *,
    rows: int,
    cols: int,
    cell_m: float,
    origin: Position = GRID_ORIGIN,
    max_altitude_m: float = 60.0,
    max_speed_mps: float = 20.0,
    sensors: list[str] | None = None,
    customers: int = 1,
    max_parallel_vvs: int = 10,
    vvs: list[dict[str, Any]] | None = None,
    name: str | None = None,
) -> dict[str, Any]:
    """A scenario with ``rows`` x ``cols`` square cells of ``cell_m`` metres, south-west corner at
    ``origin``; each cell is the operation area of one RV with its depot in the middle. The
    ground station stands at the south-west corner. Customers are named "Customer 1", ..."""
    if rows < 1 or cols < 1 or cell_m <= 0:
        raise ValueError("a grid needs at least one cell of positive size")
    vehicles = []
    for r in range(rows):
        for c in range(cols):
            corners = [
                offset(origin, north_m=r * cell_m, east_m=c * cell_m),
                offset(origin, north_m=r * cell_m, east_m=(c + 1) * cell_m),
                offset(origin, north_m=(r + 1) * cell_m, east_m=(c + 1) * cell_m),
                offset(origin, north_m=(r + 1) * cell_m, east_m=c * cell_m),
            ]
            area = [[p.lat, p.lng] for p in corners]
            area.append(area[0])
            depot = offset(origin, north_m=(r + 0.5) * cell_m, east_m=(c + 0.5) * cell_m)
            vehicles.append(
                {
                    "name": f"RV {r}-{c}",
                    "depot": [depot.lat, depot.lng, 0],
                    "area": area,
                    "min_altitude_m": 0,
                    "max_altitude_m": max_altitude_m,
                    "max_speed_mps": max_speed_mps,
                    "sensors": list(sensors or GPS_ONLY),
                }
            )
    return {
        "name": name or f"{rows}x{cols} grid of {cell_m:g} m cells",
        "ground_stations": [{"name": "GS Grid", "position": [origin.lat, origin.lng, 0]}],
        "vehicles": vehicles,
        "customers": [
            {"name": f"Customer {n + 1}", "max_parallel_vvs": max_parallel_vvs}
            for n in range(customers)
        ],
        "vvs": list(vvs or []),
    }


def grid_box(
    *, rows: int, cols: int, cell_m: float, origin: Position = GRID_ORIGIN
) -> dict[str, float]:
    """The grid's bounding box in degrees: south, west, north, east."""
    ne = offset(origin, north_m=rows * cell_m, east_m=cols * cell_m)
    return {"south": origin.lat, "west": origin.lng, "north": ne.lat, "east": ne.lng}


ORIGINAL_STYLE = """\
// In the style of the original CPCC demo programs: random points in a box, GPS readings
// stored under pos-<k> by a callback that closes over the loop variable.
var gps = VV.sensor.get('GPS');
var box = {south: %(south).7f, west: %(west).7f, north: %(north).7f, east: %(east).7f};
var low = %(low)g, high = %(high)g;
for (var k = 0; k < %(tasks)d; k++) {
  var lat = box.south + Math.random() * (box.north - box.south);
  var lng = box.west + Math.random() * (box.east - box.west);
  var alt = low + Math.random() * (high - low);
  var position = new VV.types.LatLngAlt(lat, lng, alt);
  VV.task.execute({type: 'point', position: position, tolerance: 4, sensors: [gps]}, function (data) {
    VV.storage.store('pos-' + k, data[0]);
  });
}
"""


def original_style_program(
    *,
    box: dict[str, float],
    tasks: int,
    low_m: float = 5.0,
    high_m: float = 55.0,
    margin: float = 0.02,
) -> str:
    """A VV program like the original implementation's demos, over ``box`` shrunk by ``margin``
    (a fraction of its size) so that the points keep clear of the outer border."""
    dlat = (box["north"] - box["south"]) * margin
    dlng = (box["east"] - box["west"]) * margin
    return ORIGINAL_STYLE % {
        "south": box["south"] + dlat,
        "west": box["west"] + dlng,
        "north": box["north"] - dlat,
        "east": box["east"] - dlng,
        "low": low_m,
        "high": high_m,
        "tasks": tasks,
    }


ONE_TASK = """\
// One point task, as in the original implementation's demo5: a GPS reading at a fixed point.
var gps = VV.sensor.get('GPS');
var position = new VV.types.LatLngAlt(%(lat).7f, %(lng).7f, %(alt).1f);
VV.task.execute({type: 'point', position: position, tolerance: 4, sensors: [gps]}, function (data) {
  VV.storage.store('reading', data[0]);
});
"""


def poisson_tasks(
    *,
    mean_gap_s: float,
    seed: int,
    count: int,
    box: dict[str, float],
    low_m: float = 5.0,
    high_m: float = 55.0,
) -> list[tuple[float, Position]]:
    """``count`` point tasks requested with exponentially distributed gaps of mean ``mean_gap_s``
    (Poisson arrivals), at points spread uniformly over ``box`` (see `grid_box`) between
    ``low_m`` and ``high_m`` up: (request time, position) pairs. Equal arguments, equal tasks."""
    if mean_gap_s <= 0 or count < 1:
        raise ValueError("Poisson arrivals need a positive mean gap and at least one task")
    rng = random.Random(seed)
    tasks = []
    at_s = 0.0
    for _ in range(count):
        at_s += rng.expovariate(1.0 / mean_gap_s)
        position = Position(
            rng.uniform(box["south"], box["north"]),
            rng.uniform(box["west"], box["east"]),
            rng.uniform(low_m, high_m),
        )
        tasks.append((round(at_s, 3), position))
    return tasks


def poisson_scenario(
    *,
    mean_gap_s: float,
    seed: int,
    vvs: int = 199,
    rows: int = 2,
    cols: int = 2,
    cell_m: float = 200.0,
    max_speed_mps: float = 10.0,
    overlap_m: float = 0.0,
) -> dict[str, Any]:
    """The original implementation's demo5 protocol: ``vvs`` VVs with one point task each (see
    `poisson_tasks`) over a ``rows`` x ``cols`` grid of ``cell_m`` cells, by default 4 RVs at
    10 m/s, each its own 200 m cell of a 400 m square. ``overlap_m`` > 0 widens every RV's area
    by that much on each side (within the grid), so that neighbouring areas overlap."""
    box = grid_box(rows=rows, cols=cols, cell_m=cell_m)
    programs = [
        {
            "customer": "Customer 1",
            "name": f"Task {k + 1:03d}",
            "source": ONE_TASK % {"lat": p.lat, "lng": p.lng, "alt": p.alt},
            "submit_at_s": at_s,
        }
        for k, (at_s, p) in enumerate(
            poisson_tasks(mean_gap_s=mean_gap_s, seed=seed, count=vvs, box=box)
        )
    ]
    scenario = grid_scenario(
        rows=rows,
        cols=cols,
        cell_m=cell_m,
        max_speed_mps=max_speed_mps,
        max_parallel_vvs=vvs,
        vvs=programs,
        name=f"demo5: {vvs} VVs, mean gap {mean_gap_s:g} s, seed {seed}",
    )
    if overlap_m > 0:
        for vehicle in scenario["vehicles"]:
            lats = [p[0] for p in vehicle["area"]]
            lngs = [p[1] for p in vehicle["area"]]
            low = offset(Position(min(lats), min(lngs), 0), north_m=-overlap_m, east_m=-overlap_m)
            high = offset(Position(max(lats), max(lngs), 0), north_m=overlap_m, east_m=overlap_m)
            s, w = max(box["south"], low.lat), max(box["west"], low.lng)
            n, e = min(box["north"], high.lat), min(box["east"], high.lng)
            vehicle["area"] = [[s, w], [s, e], [n, e], [n, w], [s, w]]
    return scenario
