"""The ways around no-fly zones (fleet.airspace): pure geometry, no Django."""

from __future__ import annotations

import itertools
import math
import random

import pytest
from shapely.geometry import LineString, Polygon

from fleet.airspace import CLEARANCE_M, Airspace, ExclusionZone
from fleet.geo import Position, ground_distance_m, offset

ORIGIN = Position(47.0, 8.0, 30.0)


def at(north_m: float, east_m: float, alt: float = 30.0) -> Position:
    return offset(ORIGIN.with_alt(0.0), north_m=north_m, east_m=east_m, up_m=alt)


def zone(corners: list[tuple[float, float]], low: float = 0.0, high: float | None = None):
    points = [at(n, e) for n, e in corners]
    return ExclusionZone(Polygon([(p.lng, p.lat) for p in points]), low, high)


# A wall 50 m thick from 200 m south to 200 m north of the origin, just east of it.
WALL = [(-200, 0), (-200, 50), (200, 50), (200, 0)]


def length_m(start: Position, way: list[Position]) -> float:
    points = [start, *way]
    return sum(ground_distance_m(a, b) for a, b in itertools.pairwise(points))


def clear_of(start: Position, way: list[Position], zones: list[ExclusionZone]) -> bool:
    line = LineString([(p.lng, p.lat) for p in [start, *way]])
    return not any(line.intersects(z.area) for z in zones)


def test_a_leg_nothing_is_in_the_way_of_is_flown_straight() -> None:
    air = Airspace([zone(WALL)])
    end = at(100, -100)
    assert air.way(at(0, -100), end) == [end]
    assert Airspace([]).way(at(0, -100), at(0, 200)) == [at(0, 200)]


def test_a_leg_across_a_zone_goes_round_its_nearer_end_keeping_clear() -> None:
    wall = zone(WALL)
    start, end = at(-150, -100), at(-150, 150)
    way = Airspace([wall]).way(start, end)
    assert way is not None and way[-1] == end and len(way) > 1
    assert clear_of(start, way, [wall])
    # Round the south end (200 m away), not the north one (400 m): the shortest way is the
    # taut string round the wall's corners, grown by the clearance.
    assert all(p.lat < at(-200, 0).lat for p in way[:-1])
    taut = (
        math.hypot(100 - CLEARANCE_M, 50 + CLEARANCE_M)
        + (50 + 2 * CLEARANCE_M)
        + math.hypot(100 - CLEARANCE_M, 50 + CLEARANCE_M)
    )
    assert length_m(start, way) == pytest.approx(taut, rel=0.01)


def test_every_turn_point_keeps_the_clearance() -> None:
    wall = zone(WALL)
    air = Airspace([wall])
    start, end = at(0, -100), at(0, 150)
    way = air.way(start, end)
    assert way is not None
    for turn in way[:-1]:
        nearest = min(
            ground_distance_m(turn, at(n, e)) for n, e in WALL
        )  # the turn points sit off the corners
        assert nearest >= CLEARANCE_M * 0.99


def test_altitude_changes_evenly_along_the_way() -> None:
    start, end = at(-150, -100, 20.0), at(-150, 150, 50.0)
    way = Airspace([zone(WALL)]).way(start, end)
    assert way is not None
    alts = [start.alt] + [p.alt for p in way]
    assert alts == sorted(alts)
    first = ground_distance_m(start, way[0])
    assert way[0].alt == pytest.approx(20.0 + 30.0 * first / length_m(start, way), abs=0.01)


def test_a_zone_counts_only_within_its_altitude_band() -> None:
    air = Airspace([zone(WALL, low=0.0, high=60.0)])
    above = at(0, 150, 80.0)
    assert air.way(at(0, -100, 80.0), above) == [above]  # over it
    assert len(air.way(at(0, -100, 30.0), at(0, 150, 30.0)) or []) > 1  # through it: round
    # A climb from 30 m to 80 m crosses the band on the way: round.
    assert len(air.way(at(0, -100, 30.0), above) or []) > 1
    assert air.holds(at(0, 25, 30.0)) and not air.holds(at(0, 25, 80.0))


def test_two_zones_are_passed_between_when_the_gap_is_wide_enough() -> None:
    south = zone([(-300, 0), (-300, 50), (-40, 50), (-40, 0)])
    north = zone([(40, 0), (40, 50), (300, 50), (300, 0)])
    start, end = at(0, -100), at(0, 150)
    way = Airspace([south, north]).way(start, end)
    assert way == [end]  # 80 m of gap: straight through the middle
    narrow = zone([(-5, 0), (-5, 50), (5, 50), (5, 0)])
    way = Airspace([south, north, narrow]).way(start, end)
    assert way is not None and clear_of(start, way, [south, north, narrow])
    # The gaps left (35 m each side of the plug) still let it through, between the zones.
    assert all(at(-40, 0).lat < p.lat < at(40, 0).lat for p in way)


def test_a_position_walled_in_by_zones_has_no_way() -> None:
    box = [
        zone([(-100, -100), (-100, 100), (-80, 100), (-80, -100)]),
        zone([(80, -100), (80, 100), (100, 100), (100, -100)]),
        zone([(-100, -100), (-100, -80), (100, -80), (100, -100)]),
        zone([(-100, 80), (-100, 100), (100, 100), (100, 80)]),
    ]
    assert Airspace(box).way(at(0, -300), at(0, 0)) is None


def test_a_vehicle_inside_a_zone_leaves_it_and_a_point_close_to_one_is_reached() -> None:
    wall = zone(WALL)
    air = Airspace([wall])
    inside = at(0, 25)
    end = at(0, -100)
    assert air.way(inside, end) == [end]
    close = at(0, 52)  # 2 m east of the wall
    way = air.way(at(0, 150), close)
    assert way == [close]
    way = air.way(at(0, -100), close)
    assert way is not None and way[-1] == close and clear_of(at(0, -100), way[:-1], [wall])


def test_near_pairs_include_every_leg_that_is_not_straight() -> None:
    rng = random.Random(7)
    zones = [zone(WALL), zone([(250, -150), (250, -100), (300, -100), (300, -150)], high=40.0)]
    air = Airspace(zones)
    points = [
        at(rng.uniform(-400, 400), rng.uniform(-300, 300), rng.choice([20, 50])) for _ in range(60)
    ]
    near = set(air.near_pairs(points))
    for i, j in itertools.combinations(range(len(points)), 2):
        if air.way(points[i], points[j]) != [points[j]]:
            assert (i, j) in near
    assert len(near) < len(points) * (len(points) - 1) // 2  # far from all of them


def test_a_clearance_must_be_positive() -> None:
    with pytest.raises(ValueError, match="clearance_m must be a positive finite number"):
        Airspace([zone(WALL)], clearance_m=0.0)
