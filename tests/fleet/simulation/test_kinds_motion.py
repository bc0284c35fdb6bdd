"""How each kind of vehicle moves: rovers and boats turn in place and stay in the plane, subs
dive and rise at their own rates and surface to dock; copters are as they always were."""

import pytest

from fleet.geo import Position, ground_distance_m, offset
from fleet.kinds import LIMITS
from fleet.simulation.vehicle import SimVehicle, VehicleSpec

DEPOT = Position(47.0, 15.0, 0.0)
NORTH = offset(DEPOT, north_m=100.0, east_m=0.0)
# 100 m east of NORTH: after driving north, a right turn of 90 degrees.
NORTH_EAST = offset(NORTH, north_m=0.0, east_m=100.0)


def _rover(kind: str = "ground", **spec: float) -> SimVehicle:
    return SimVehicle(VehicleSpec(max_speed_mps=5.0, kind=kind, **spec), DEPOT)


def _phases(vehicle: SimVehicle, from_s: float) -> list[str]:
    return [leg.phase for leg in vehicle.planned_legs(from_s)]


@pytest.mark.parametrize("kind", ["ground", "surface"])
def test_a_right_angle_turn_costs_ninety_degrees_at_the_turn_rate(kind: str) -> None:
    rover = _rover(kind, turn_rate_dps=45.0)
    # A new vehicle faces north: no turn before the first leg north.
    there = rover.fly_to(NORTH, 0.0)
    assert there == pytest.approx(100.0 / 5.0)
    assert _phases(rover, 0.0) == ["cruise"]

    arrival = rover.fly_to(NORTH_EAST, there)

    assert _phases(rover, there) == ["turning", "cruise"]
    turn_s = 90.0 / 45.0
    assert arrival - there == pytest.approx(turn_s + 100.0 / 5.0, abs=0.01)
    # It turns where it stands, not moving, then drives.
    assert rover.position_at(there + turn_s / 2) == NORTH
    assert rover.phase_at(there + turn_s / 2) == "turning"
    assert rover.speed_at(there + turn_s / 2) == 0.0
    assert rover.position_at(arrival) == NORTH_EAST


def test_without_a_turn_rate_a_rover_turns_at_its_kinds_default() -> None:
    rover = _rover("ground")
    east = offset(DEPOT, north_m=0.0, east_m=50.0)

    arrival = rover.fly_to(east, 0.0)

    default_dps = LIMITS["ground"].turn_rate_dps
    assert default_dps is not None
    assert arrival == pytest.approx(90.0 / default_dps + 50.0 / 5.0, abs=0.01)
    assert rover.time_to_s(east, 0.0) == pytest.approx(arrival)


def test_a_turn_goes_the_shortest_way() -> None:
    rover = _rover(turn_rate_dps=10.0)
    west = offset(DEPOT, north_m=0.0, east_m=-50.0)  # 90 degrees left, not 270 right

    assert rover.fly_to(west, 0.0) == pytest.approx(9.0 + 10.0, abs=0.01)


def test_the_time_to_a_target_counts_the_turn_from_the_current_heading() -> None:
    rover = _rover(turn_rate_dps=45.0)
    there = rover.fly_to(NORTH, 0.0)

    estimate = rover.time_to_s(NORTH_EAST, there)

    assert estimate == pytest.approx(rover.fly_to(NORTH_EAST, there) - there)
    # A leg alone knows no heading: no turn in it.
    assert rover.leg_s(NORTH, NORTH_EAST) == pytest.approx(100.0 / 5.0, abs=0.01)


def test_a_turn_cut_short_continues_from_the_heading_reached() -> None:
    rover = _rover(turn_rate_dps=10.0)
    east = offset(DEPOT, north_m=0.0, east_m=50.0)
    rover.fly_to(east, 0.0)  # a 9 s turn to the right first

    # Told after 3 s (30 degrees right) to go north after all: 30 degrees back.
    arrival = rover.fly_to(NORTH, 3.0)

    assert arrival == pytest.approx(3.0 + 3.0 + 100.0 / 5.0, abs=0.01)


@pytest.mark.parametrize("kind", ["ground", "surface"])
def test_a_vehicle_in_the_plane_never_climbs_and_refuses_a_target_up_high(kind: str) -> None:
    rover = _rover(kind, turn_rate_dps=45.0)
    rover.fly_to(NORTH, 0.0)

    with pytest.raises(ValueError, match=f"a {kind} vehicle moves in the plane at 0 m"):
        rover.fly_to(NORTH_EAST.with_alt(10.0), 5.0)

    # The refused command left the plan as it was: it still arrives north, at altitude 0.
    assert rover.position_at(20.0) == NORTH
    assert {leg.start.alt for leg in rover.planned_legs(0.0)} == {0.0}
    assert {leg.end.alt for leg in rover.planned_legs(0.0)} == {0.0}


def test_a_rover_leaves_its_depot_without_a_take_off_and_parks_on_return() -> None:
    rover = _rover(turn_rate_dps=45.0)
    assert rover.is_landed_at(0.0)
    there = rover.fly_to(NORTH_EAST, 0.0)
    assert "takeoff" not in _phases(rover, 0.0)
    assert not rover.is_landed_at(there / 2)
    assert rover.phase_at(there + 1.0) == "hovering"  # stopped on the way

    home = rover.return_to_depot(there + 1.0)

    assert _phases(rover, there + 1.0) == ["turning", "cruise"]
    assert rover.position_at(home) == DEPOT
    assert rover.phase_at(home) == "landed"
    assert rover.is_landed_at(home + 10.0)


def test_a_rover_told_to_land_stops_where_it_is() -> None:
    rover = _rover(turn_rate_dps=45.0)
    rover.fly_to(NORTH, 0.0)
    here = rover.position_at(10.0)

    stopped = rover.land(10.0)

    assert stopped == 10.0
    assert rover.is_landed_at(10.0)
    assert rover.position_at(60.0) == here


def test_a_rovers_battery_and_odometer_count_time_and_distance_away_from_parking() -> None:
    rover = SimVehicle(
        VehicleSpec(max_speed_mps=5.0, kind="ground", turn_rate_dps=45.0, battery_s=600.0), DEPOT
    )
    there = rover.fly_to(NORTH, 0.0)
    arrival = rover.fly_to(NORTH_EAST, there + 10.0)  # 10 s stopped, a 2 s turn, a 20 s leg
    home = rover.return_to_depot(arrival)

    assert rover.flight_s(arrival) == pytest.approx(arrival)
    assert rover.distance_m(arrival) == pytest.approx(200.0, abs=0.01)
    assert rover.battery_remaining_s(home + 100.0) == pytest.approx(600.0 - home)


def test_a_sub_dives_at_its_dive_rate_and_rises_at_its_climb_rate() -> None:
    sub = SimVehicle(
        VehicleSpec(max_speed_mps=2.0, climb_rate_mps=1.0, dive_rate_mps=0.5, kind="underwater"),
        DEPOT,
    )
    deep = offset(DEPOT, north_m=10.0, east_m=0.0, up_m=-20.0)

    down = sub.fly_to(deep, 0.0)

    # 20 m down at 0.5 m/s outlasts 10 m along at 2 m/s; no take-off leg, it dives on the way.
    assert down == pytest.approx(40.0)
    assert _phases(sub, 0.0) == ["cruise"]
    assert sub.position_at(down) == deep
    assert sub.position_at(20.0).alt == pytest.approx(-10.0)
    shallow = deep.with_alt(-5.0)
    assert sub.fly_to(shallow, down) - down == pytest.approx(15.0)  # 15 m up at 1 m/s


def test_a_sub_returning_home_surfaces_then_cruises_to_its_dock() -> None:
    sub = SimVehicle(
        VehicleSpec(max_speed_mps=2.0, climb_rate_mps=1.0, dive_rate_mps=0.5, kind="underwater"),
        DEPOT,
    )
    deep = offset(DEPOT, north_m=10.0, east_m=0.0, up_m=-20.0)
    down = sub.fly_to(deep, 0.0)
    assert sub.time_home_s(deep) == pytest.approx(20.0 + 5.0)

    home = sub.return_to_depot(down)

    assert home - down == pytest.approx(20.0 + 5.0)
    assert sub.position_at(down + 20.0) == deep.with_alt(0.0)  # surfaced where it was
    assert sub.position_at(home) == DEPOT
    assert sub.is_landed_at(home)


def test_a_sub_told_to_land_surfaces_where_it_is() -> None:
    sub = SimVehicle(VehicleSpec(max_speed_mps=2.0, climb_rate_mps=1.0, kind="underwater"), DEPOT)
    deep = offset(DEPOT, north_m=10.0, east_m=0.0, up_m=-20.0)
    down = sub.fly_to(deep, 0.0)

    up = sub.land(down)

    assert up - down == pytest.approx(20.0)
    assert sub.phase_at(down + 1.0) == "landing"
    assert sub.position_at(up) == deep.with_alt(0.0)
    assert sub.is_landed_at(up)


def test_a_sub_goes_no_higher_than_the_surface() -> None:
    sub = SimVehicle(VehicleSpec(max_speed_mps=2.0, kind="underwater"), DEPOT)

    with pytest.raises(ValueError, match="no higher than the surface"):
        sub.fly_to(NORTH.with_alt(5.0), 0.0)


def test_a_copter_is_unchanged_by_a_turn_rate_and_still_takes_off() -> None:
    plain = SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=2.0), DEPOT)
    turned = SimVehicle(
        VehicleSpec(max_speed_mps=10.0, climb_rate_mps=2.0, turn_rate_dps=5.0), DEPOT
    )
    target = NORTH_EAST.with_alt(20.0)

    for copter in (plain, turned):
        arrival = copter.fly_to(target, 0.0)
        assert _phases(copter, 0.0) == ["takeoff", "cruise"]
        assert arrival == 10.0 + ground_distance_m(DEPOT, target) / 10.0


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ({"kind": "hovercraft"}, "unknown vehicle kind 'hovercraft': one of aerial, ground"),
        ({"dive_rate_mps": 0.0}, "dive_rate_mps must be a positive finite number, got 0.0"),
        ({"dive_rate_mps": float("nan")}, "dive_rate_mps must be a positive finite number"),
        ({"turn_rate_dps": -30.0}, "turn_rate_dps must be a positive finite number, got -30.0"),
    ],
)
def test_a_spec_refuses_bad_values_naming_the_field(spec: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        VehicleSpec(max_speed_mps=5.0, **spec)  # type: ignore[arg-type]
