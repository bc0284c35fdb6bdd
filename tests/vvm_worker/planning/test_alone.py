"""What a class would get alone (vvm_worker.planning.alone): a replay of its requests on one
vehicle, planned as the vehicle plans, flown at its leg times, each reading costing what a
reading cost the vehicle."""

from __future__ import annotations

import pytest

from fleet.geo import Position, distance_m, offset
from vvm_worker.planning import make_planner
from vvm_worker.planning.alone import (
    AloneRequest,
    AloneVehicle,
    Reading,
    alone_latencies,
    reading_overhead,
)

pytestmark = pytest.mark.backend_independent("pure planning: no database")

HOME = Position(47.0, 8.0, 10.0)


def leg(a: Position, b: Position) -> float:
    """10 m/s, level: a second for every 10 m."""
    return distance_m(a, b) / 10.0


def at(east_m: float) -> Position:
    return offset(HOME, north_m=0.0, east_m=east_m)


def request(rid: int, east_m: float, requested_s: float, **terms: float) -> AloneRequest:
    return AloneRequest(rid, at(east_m), requested_s, ready_s=requested_s + 1.0, read_by=1, **terms)


def rv(rid: int = 1, *, start: Position = HOME, overhead_s: float = 0.0, **more) -> AloneVehicle:
    return AloneVehicle(
        rid, start, leg, lambda: make_planner("latency", cost=leg), overhead_s=overhead_s, **more
    )


def replay(requests: list[AloneRequest], *rvs: AloneVehicle) -> dict[int, float]:
    return {k: round(v, 6) for k, v in alone_latencies(requests, rvs or (rv(),)).items()}


def test_requests_far_apart_in_time_each_take_the_flight_to_them_and_the_reading() -> None:
    # Reached a second after the request; 100 m at 10 m/s; 2 s to read.
    got = replay([request(1, 100.0, 0.0), request(2, 200.0, 500.0)], rv(overhead_s=2.0))
    assert got == {1: 1.0 + 10.0 + 2.0, 2: 1.0 + 10.0 + 2.0}


def test_requests_at_once_queue_behind_each_other_in_the_planners_order() -> None:
    got = replay([request(1, 300.0, 0.0), request(2, 100.0, 0.0)])
    # The nearer first (10 s), then 20 s further on: the order that keeps them waiting least.
    assert got == {2: 11.0, 1: 31.0}


def test_an_earlier_deadline_is_served_first_when_it_would_be_late_otherwise() -> None:
    # Without deadlines the near one goes first; the far one's deadline (35 s) says otherwise.
    got = replay([request(1, 100.0, 0.0), request(2, -300.0, 0.0, deadline_s=35.0)])
    assert got == {2: 31.0, 1: 71.0}


def test_a_request_goes_to_the_rv_the_mapper_would_send_it_to() -> None:
    # RV 2 starts 1 km east: the first request (near home) goes to RV 1, the second (near RV
    # 2) to RV 2, both served at once; a point only RV 2 covers goes to it, however far.
    east = rv(2, start=at(1_000.0))
    got = replay([request(1, 100.0, 0.0), request(2, 900.0, 0.0)], rv(), east)
    assert got == {1: 11.0, 2: 11.0}
    west_only = rv(covers=lambda p: p.lng < HOME.lng)
    assert replay([request(3, 100.0, 0.0)], west_only, east) == {3: 1.0 + 90.0}


def test_an_idle_rv_stands_by_then_flies_home_and_takes_off_again() -> None:
    # It waits at its standby spot 50 m east for 120 s after a reading, then flies home and
    # lands. From the ground it climbs straight up (1 s to 10 m at this leg time) first.
    ground = HOME.with_alt(0.0)
    waiting = rv(start=ground, standby=at(50.0), takeoff_alt_m=5.0)
    first = request(1, 100.0, 0.0)
    assert replay([first, request(2, 100.0, 60.0)], waiting) == {
        1: pytest.approx(1.0 + 1.0 + 10.0),
        2: pytest.approx(1.0 + 5.0),  # from the standby spot
    }
    assert replay([first, request(3, 100.0, 600.0)], waiting)[3] == pytest.approx(12.0)
    assert replay([request(3, 100.0, 600.0)], rv(start=ground))[3] == pytest.approx(
        1.0 + distance_m(ground, at(100.0)) / 10.0
    ), "a vehicle that does not take off flies straight"


def test_a_point_nobody_covers_stays_with_the_rv_that_read_it() -> None:
    nowhere = rv(covers=lambda p: False)
    assert replay([request(1, 100.0, 0.0)], nowhere) == {1: 11.0}
    with pytest.raises(ValueError, match="read by RV 1, not given"):
        replay([request(1, 100.0, 0.0)], rv(5, covers=lambda p: False))


def test_nothing_to_replay_gives_nothing() -> None:
    assert replay([]) == {}


def test_a_readings_cost_is_measured_where_the_vehicle_went_straight_on() -> None:
    readings = [
        Reading(at(100.0), requested_s=0.0, done_s=13.0),
        Reading(at(200.0), requested_s=5.0, done_s=26.0),  # waiting: 10 s flight + 3 s
        Reading(at(300.0), requested_s=20.0, done_s=40.0),  # waiting: 10 s flight + 4 s
        Reading(at(400.0), requested_s=100.0, done_s=150.0),  # idle before: not counted
    ]
    assert reading_overhead(readings, leg=leg) == pytest.approx(4.0)  # the median of 3 and 4
    assert reading_overhead(readings[:1], leg=leg) == 0.0
