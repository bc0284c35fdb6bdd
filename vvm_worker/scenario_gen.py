"""Generated scenarios: a grid of square cells with one RV each, and original-style VV programs.

Pure Python (no Django). The scenarios follow the contract of DESIGN.md section 5, so they run
through ``parse_scenario`` and ``simulate`` like a file would.
"""

from __future__ import annotations

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
