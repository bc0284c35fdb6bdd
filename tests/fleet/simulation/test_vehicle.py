"""The kinematic vehicle: take-off, cruise, interruption, return, odometry and battery."""

import pytest

from fleet.geo import Position, distance_m, ground_distance_m, offset
from fleet.simulation import Leg, SimVehicle, VehicleSpec

DEPOT = Position(47.0, 15.0, 0.0)
SPEC = VehicleSpec(max_speed_mps=10.0, climb_rate_mps=2.0, takeoff_alt_m=5.0)
# 300 m north and 400 m east: 500 m along the ground, 20 m up.
TARGET = offset(DEPOT, north_m=300.0, east_m=400.0, up_m=20.0)


def _vehicle(spec: VehicleSpec = SPEC, now_s: float = 0.0) -> SimVehicle:
    return SimVehicle(spec, DEPOT, now_s=now_s)


def test_take_off_then_cruise_reaches_target_exactly_at_the_returned_time() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)

    takeoff_s = 20.0 / 2.0
    cruise_s = ground_distance_m(DEPOT.with_alt(20.0), TARGET) / 10.0
    assert arrival == pytest.approx(takeoff_s + cruise_s)
    assert vehicle.position_at(arrival) == TARGET
    assert vehicle.position_at(takeoff_s) == DEPOT.with_alt(20.0)
    assert [leg.phase for leg in vehicle.planned_legs(0.0)] == ["takeoff", "cruise"]


def test_leg_duration_is_set_by_the_slower_of_speed_and_climb_rate() -> None:
    vehicle = _vehicle()
    hover_at = vehicle.fly_to(TARGET, 0.0)
    # 30 m away but 40 m higher: climbing at 2 m/s takes 20 s, flying 30 m only 3 s.
    steep = offset(TARGET, north_m=30.0, east_m=0.0, up_m=40.0)

    arrival = vehicle.fly_to(steep, hover_at)

    assert arrival - hover_at == pytest.approx(20.0)
    assert vehicle.position_at(arrival) == steep


def test_target_below_take_off_altitude_is_still_reached_exactly() -> None:
    vehicle = _vehicle()
    low = offset(DEPOT, north_m=500.0, east_m=0.0, up_m=2.0)

    arrival = vehicle.fly_to(low, 0.0)

    legs = vehicle.planned_legs(0.0)
    assert legs[0].end.alt == 5.0
    assert arrival == pytest.approx(5.0 / 2.0 + 500.0 / 10.0, rel=1e-6)
    assert vehicle.position_at(arrival) == low


def test_position_in_the_middle_of_a_leg_lies_between_its_ends() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)
    mid = (10.0 + arrival) / 2.0

    here = vehicle.position_at(mid)

    top = DEPOT.with_alt(20.0)
    assert distance_m(top, here) == pytest.approx(250.0, abs=0.01)
    assert distance_m(here, TARGET) == pytest.approx(250.0, abs=0.01)
    assert here.alt == pytest.approx(20.0)


def test_phases_through_a_whole_flight() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)
    landing = vehicle.return_to_depot(arrival + 30.0)

    assert vehicle.phase_at(-1.0) == "landed"
    assert vehicle.phase_at(5.0) == "takeoff"
    assert vehicle.phase_at(30.0) == "cruise"
    assert vehicle.phase_at(arrival + 10.0) == "hovering"
    assert vehicle.phase_at(landing - 1.0) == "landing"
    assert vehicle.phase_at(landing) == "landed"
    assert vehicle.is_landed_at(landing + 100.0)
    assert not vehicle.is_landed_at(arrival)


def test_interrupting_a_cruise_continues_from_where_the_vehicle_is() -> None:
    vehicle = _vehicle()
    vehicle.fly_to(TARGET, 0.0)
    t = 35.0  # 25 s into the cruise leg
    here = vehicle.position_at(t)
    flown = vehicle.distance_m(t)
    detour = offset(DEPOT, north_m=-200.0, east_m=0.0, up_m=20.0)

    arrival = vehicle.fly_to(detour, t)

    assert vehicle.position_at(t) == here
    assert vehicle.distance_m(t) == pytest.approx(flown)
    assert flown == pytest.approx(20.0 + 250.0, abs=0.01)
    legs = vehicle.planned_legs(t)
    assert len(legs) == 1
    assert legs[0].start == here
    assert legs[0].phase == "cruise"
    assert arrival == pytest.approx(t + ground_distance_m(here, detour) / 10.0)
    assert vehicle.position_at(arrival) == detour
    # The unflown half of the first cruise is not on the odometer.
    assert vehicle.distance_m(arrival) == pytest.approx(flown + distance_m(here, detour), abs=0.01)


def test_interrupting_a_landing_flies_on_without_a_new_take_off() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)
    landing = vehicle.return_to_depot(arrival)
    t = landing - 5.0  # 10 m above the depot, going down

    vehicle.fly_to(TARGET, t)

    assert [leg.phase for leg in vehicle.planned_legs(t)] == ["cruise"]
    assert not vehicle.is_landed_at(landing)


def test_return_to_depot_cruises_at_altitude_then_lands_vertically() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)

    landing = vehicle.return_to_depot(arrival)

    legs = vehicle.planned_legs(arrival)
    assert [leg.phase for leg in legs] == ["cruise", "landing"]
    assert legs[1].start == DEPOT.with_alt(20.0)
    assert legs[1].end == DEPOT
    assert landing == pytest.approx(arrival + 500.0 / 10.0 + 20.0 / 2.0, rel=1e-6)
    assert vehicle.position_at(landing) == DEPOT
    assert vehicle.is_landed_at(landing)


def test_return_to_depot_from_low_altitude_climbs_to_take_off_altitude() -> None:
    vehicle = _vehicle()
    ground_task = offset(DEPOT, north_m=100.0, east_m=0.0, up_m=0.0)
    arrival = vehicle.fly_to(ground_task, 0.0)

    vehicle.return_to_depot(arrival)

    cruise, landing = vehicle.planned_legs(arrival)
    assert cruise.end == DEPOT.with_alt(5.0)
    assert landing.end == DEPOT


def test_commands_that_need_no_flight_return_now() -> None:
    vehicle = _vehicle()
    assert vehicle.return_to_depot(3.0) == 3.0
    assert vehicle.fly_to(DEPOT, 4.0) == 4.0
    assert vehicle.is_landed_at(4.0)

    arrival = vehicle.fly_to(TARGET, 10.0)
    assert vehicle.fly_to(TARGET, arrival + 5.0) == arrival + 5.0
    assert vehicle.planned_legs(arrival + 5.0) == []
    assert vehicle.phase_at(arrival + 6.0) == "hovering"


def test_landed_time_is_not_flight_time_and_odometer_counts_the_whole_path() -> None:
    vehicle = _vehicle()
    take_off_at = 100.0  # sits on the ground for 100 s first
    arrival = vehicle.fly_to(TARGET, take_off_at)
    landing = vehicle.return_to_depot(arrival)

    assert vehicle.flight_s(take_off_at) == 0.0
    assert vehicle.flight_s(landing + 1000.0) == pytest.approx(landing - take_off_at)
    assert vehicle.distance_m(landing + 1000.0) == pytest.approx(20.0 + 500.0 + 500.0 + 20.0)


def test_distance_and_flight_time_are_interpolated_inside_a_leg() -> None:
    vehicle = _vehicle()
    vehicle.fly_to(TARGET, 0.0)

    assert vehicle.distance_m(5.0) == pytest.approx(10.0)
    assert vehicle.flight_s(5.0) == pytest.approx(5.0)
    assert vehicle.distance_m(20.0) == pytest.approx(20.0 + 100.0, abs=0.01)


def test_hovering_counts_as_flight_time_but_not_as_distance() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)

    assert vehicle.flight_s(arrival + 100.0) == pytest.approx(arrival + 100.0)
    assert vehicle.distance_m(arrival + 100.0) == pytest.approx(vehicle.distance_m(arrival))


def test_battery_remaining_is_endurance_minus_flight_time() -> None:
    vehicle = _vehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=2.0, battery_s=600.0))
    arrival = vehicle.fly_to(TARGET, 0.0)

    assert vehicle.battery_remaining_s(0.0) == 600.0
    assert vehicle.battery_remaining_s(arrival) == pytest.approx(600.0 - arrival)
    # Not enforced, only reported: an over-long hover bottoms out at zero.
    assert vehicle.battery_remaining_s(10_000.0) == 0.0
    assert _vehicle().battery_remaining_s(50.0) is None


def test_vehicle_can_fly_again_after_landing() -> None:
    vehicle = _vehicle()
    landing = vehicle.return_to_depot(vehicle.fly_to(TARGET, 0.0))

    arrival = vehicle.fly_to(TARGET, landing + 60.0)

    assert vehicle.phase_at(landing + 61.0) == "takeoff"
    assert vehicle.position_at(arrival) == TARGET
    assert vehicle.flight_s(arrival) == pytest.approx(landing + (arrival - landing - 60.0))


def test_planned_legs_is_the_rest_of_the_plan_cut_at_from_s() -> None:
    vehicle = _vehicle()
    arrival = vehicle.fly_to(TARGET, 0.0)

    legs = vehicle.planned_legs(20.0)

    assert legs == [Leg(20.0, arrival, vehicle.position_at(20.0), TARGET, "cruise")]
    assert vehicle.planned_legs(arrival) == []


def test_a_command_earlier_than_the_previous_one_is_refused() -> None:
    vehicle = _vehicle(now_s=10.0)
    with pytest.raises(ValueError, match="earlier than the previous command"):
        vehicle.fly_to(TARGET, 5.0)
    vehicle.fly_to(TARGET, 20.0)
    with pytest.raises(ValueError, match="earlier than the previous command"):
        vehicle.return_to_depot(19.0)
    with pytest.raises(ValueError, match="finite"):
        vehicle.fly_to(TARGET, float("nan"))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"max_speed_mps": 0.0}, "max_speed_mps"),
        ({"max_speed_mps": -3.0}, "max_speed_mps"),
        ({"max_speed_mps": 5.0, "climb_rate_mps": 0.0}, "climb_rate_mps"),
        ({"max_speed_mps": 5.0, "takeoff_alt_m": -1.0}, "takeoff_alt_m"),
        ({"max_speed_mps": 5.0, "battery_s": 0.0}, "battery_s"),
    ],
)
def test_bad_vehicle_spec_is_refused_naming_the_field(kwargs: dict[str, float], name: str) -> None:
    with pytest.raises(ValueError, match=name):
        VehicleSpec(**kwargs)


def test_the_estimates_are_what_the_commands_then_take() -> None:
    vehicle = _vehicle()
    estimate = vehicle.time_to_s(TARGET, 0.0)
    arrival = vehicle.fly_to(TARGET, 0.0)
    assert estimate == pytest.approx(arrival)
    home = vehicle.time_home_s(TARGET)
    assert vehicle.return_to_depot(arrival) == pytest.approx(arrival + home)


def test_a_recharged_battery_is_full_once_the_charge_is_done() -> None:
    spec = VehicleSpec(max_speed_mps=10.0, climb_rate_mps=2.0, takeoff_alt_m=5.0, battery_s=600.0)
    vehicle = _vehicle(spec)
    landed = vehicle.return_to_depot(vehicle.fly_to(TARGET, 0.0))
    used = vehicle.flight_s(landed)
    assert vehicle.battery_remaining_s(landed) == pytest.approx(600.0 - used)
    full = vehicle.recharge(landed, 120.0)
    assert full == landed + 120.0
    assert vehicle.battery_remaining_s(full - 1) == pytest.approx(600.0 - used), "still charging"
    assert vehicle.battery_remaining_s(full) == 600.0
    back = vehicle.fly_to(TARGET, full + 10)
    assert vehicle.battery_remaining_s(back) == pytest.approx(600.0 - (back - full - 10))


def test_only_a_landed_vehicle_charges() -> None:
    vehicle = _vehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=2.0, battery_s=60.0))
    arrival = vehicle.fly_to(TARGET, 0.0)
    with pytest.raises(ValueError, match="not landed"):
        vehicle.recharge(arrival, 10.0)


def test_a_vehicle_that_starts_in_the_air_flies_from_there_without_a_take_off() -> None:
    v = _vehicle()
    above = Position(47.001, 15.0, 30.0)
    v.hover_at(above, 0.0)
    assert v.position_at(0.0) == above and v.phase_at(5.0) == "hovering"
    target = Position(47.001, 15.001, 30.0)
    arrives = v.fly_to(target, 10.0)
    # One straight cruise leg from where it hovers: no climb from its depot first.
    assert arrives == pytest.approx(10.0 + v.leg_s(above, target))
    assert v.phase_at(11.0) == "cruise"
    with pytest.raises(ValueError, match="before its first command"):
        v.hover_at(above, 20.0)
    with pytest.raises(ValueError, match="above its depot"):
        _vehicle().hover_at(DEPOT, 0.0)
