"""The one travel-time formula: its scalar and array forms agree, and the simulator flies what
it says (the driver's estimates and the planners' costs call the same functions)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.geo import Position, ground_distance_m
from fleet.kinematics import from_ground_s, leg_s, legs_s, take_off_top
from fleet.simulation import SimVehicle, VehicleSpec
from vvm_worker.planning.costs import TravelTime, build_cost_matrix

positions = st.builds(
    Position,
    lat=st.floats(48.0, 48.2),
    lng=st.floats(12.8, 13.0),
    alt=st.floats(0.0, 150.0),
)
rates = st.floats(0.5, 30.0)


@settings(max_examples=60, deadline=None)
@given(
    points=st.lists(positions, min_size=1, max_size=8),
    speed=rates,
    climb=rates,
    descent=st.one_of(st.none(), rates),
)
def test_the_array_form_is_the_scalar_form_for_every_pair(points, speed, climb, descent) -> None:
    descent = climb if descent is None else descent
    n = len(points)
    ground = np.array([[ground_distance_m(a, b) for b in points] for a in points])
    alt = np.array([p.alt for p in points])
    legs = legs_s(ground, alt, speed_mps=speed, climb_mps=climb, descent_mps=descent)
    expected = np.array(
        [
            [leg_s(a, b, speed_mps=speed, climb_mps=climb, descent_mps=descent) for b in points]
            for a in points
        ]
    )
    assert legs.shape == (n, n)
    np.testing.assert_allclose(legs, expected, rtol=1e-12, atol=1e-9)


def test_a_leg_lasts_its_slower_part() -> None:
    start = Position(48.1, 12.9, 10.0)
    east = Position(48.1, 12.9 + 0.01, 10.0)  # about 743 m
    ground = ground_distance_m(start, east)
    rates = {"speed_mps": 10.0, "climb_mps": 2.0, "descent_mps": 1.0}
    assert leg_s(start, east, **rates) == pytest.approx(ground / 10.0)
    assert leg_s(start, start.with_alt(110.0), **rates) == pytest.approx(50.0)  # climbing
    assert leg_s(start.with_alt(110.0), start, **rates) == pytest.approx(100.0)  # descending
    # Far and a little higher: the horizontal part sets the time.
    assert leg_s(start, east.with_alt(20.0), **rates) == pytest.approx(ground / 10.0)


def test_from_the_ground_the_vehicle_rises_first() -> None:
    here = Position(48.1, 12.9, 0.0)
    low = Position(48.1, 12.901, 2.0)
    assert take_off_top(here, low, takeoff_alt_m=5.0) == here.with_alt(5.0)
    assert take_off_top(here.with_alt(8.0), low, takeoff_alt_m=5.0) == here.with_alt(8.0)
    rates = {"speed_mps": 10.0, "climb_mps": 2.5, "descent_mps": 2.5}
    seconds = from_ground_s(here, low, takeoff_alt_m=5.0, **rates)
    after_climb = leg_s(here.with_alt(5.0), low, **rates)
    assert seconds == pytest.approx(2.0 + after_climb)


@settings(max_examples=30, deadline=None)
@given(target=positions, speed=rates, climb=rates, takeoff=st.floats(0.0, 30.0))
def test_the_simulator_flies_what_the_formula_says(target, speed, climb, takeoff) -> None:
    spec = VehicleSpec(max_speed_mps=speed, climb_rate_mps=climb, takeoff_alt_m=takeoff)
    depot = Position(48.1, 12.9, 0.0)
    vehicle = SimVehicle(spec, depot)
    rates = {"speed_mps": speed, "climb_mps": climb, "descent_mps": climb}
    expected = from_ground_s(depot, target, takeoff_alt_m=takeoff, **rates)
    assert vehicle.time_to_s(target, 0.0) == expected
    assert vehicle.fly_to(target, 0.0) == pytest.approx(expected, rel=1e-12, abs=1e-9)
    # The planners' costs: the same legs.
    cost = TravelTime(max_speed_mps=speed, climb_rate_mps=climb)
    matrix = build_cost_matrix(cost, depot, [target, depot.with_alt(takeoff)])
    assert matrix.values[1, 2] == leg_s(target, depot.with_alt(takeoff), **rates)
