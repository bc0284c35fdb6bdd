"""fleet/service_area.py: the service area per altitude band, without Django."""

from __future__ import annotations

from shapely.geometry import Polygon, box, shape

from fleet.service_area import Exclusion, Reach, service_area_geojson, service_bands

WEST = box(0.0, 0.0, 1.0, 1.0)
EAST = box(1.0, 0.0, 2.0, 1.0)
FAR = box(5.0, 5.0, 6.0, 6.0)


def _bands(reaches: list[Reach]) -> list[tuple[float, float, float]]:
    """Each band as (low, high, area in square degrees)."""
    return [
        (b.min_altitude_m, b.max_altitude_m, round(b.area.area, 9)) for b in service_bands(reaches)
    ]


def test_overlapping_ranges_make_a_band_for_each_piece_of_altitude() -> None:
    # West flies 0-120 m, East 20-60 m: between 20 and 60 m both areas serve.
    bands = _bands([Reach(WEST, 0.0, 120.0), Reach(EAST, 20.0, 60.0)])
    assert bands == [(0.0, 20.0, 1.0), (20.0, 60.0, 2.0), (60.0, 120.0, 1.0)]


def test_the_same_ground_at_neighbouring_altitudes_is_one_band() -> None:
    # Two vehicles over the same ground, 0-50 m and 50-100 m: one band 0-100 m.
    assert _bands([Reach(WEST, 0.0, 50.0), Reach(WEST, 50.0, 100.0)]) == [(0.0, 100.0, 1.0)]


def test_areas_apart_stay_apart_and_no_fleet_serves_nowhere() -> None:
    (band,) = service_bands([Reach(WEST, 0.0, 100.0), Reach(FAR, 0.0, 100.0)])
    assert band.area.geom_type == "MultiPolygon" and round(band.area.area, 9) == 2.0
    assert service_bands([]) == []


def test_a_vehicle_of_one_altitude_still_serves_there() -> None:
    assert _bands([Reach(WEST, 30.0, 30.0)]) == [(30.0, 30.0, 1.0)]


def test_the_geojson_holds_bands_then_zones_counter_clockwise() -> None:
    clockwise = Polygon([(0, 0), (0, 1), (1, 1), (1, 0), (0, 0)])
    collection = service_area_geojson(
        [Reach(clockwise, 10.0, 90.0)], [Exclusion(box(0.2, 0.2, 0.4, 0.4), 0.0, None)]
    )
    assert collection["type"] == "FeatureCollection"
    service, no_fly = collection["features"]
    assert service["properties"] == {
        "kind": "service",
        "min_altitude_m": 10.0,
        "max_altitude_m": 90.0,
    }
    assert no_fly["properties"] == {"kind": "no_fly", "min_altitude_m": 0.0, "max_altitude_m": None}
    ring = Polygon(service["geometry"]["coordinates"][0])
    assert ring.exterior.is_ccw, "RFC 7946: outer rings counter-clockwise"
    assert shape(service["geometry"]).equals(clockwise)
