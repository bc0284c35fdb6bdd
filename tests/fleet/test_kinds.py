"""The limits of each vehicle kind (fleet.kinds) and the model's validation by kind."""

from __future__ import annotations

import pytest
from django.core.exceptions import ValidationError

from fleet.kinds import AERIAL, GROUND, KINDS, SURFACE, UNDERWATER, limit_problems, limits_of
from fleet.models import Vehicle

SQUARE = [[0.0, 0.0], [0.0, 0.01], [0.01, 0.01], [0.01, 0.0], [0.0, 0.0]]


def test_every_kind_has_limits_and_an_unknown_kind_names_the_kinds_there_are() -> None:
    assert [limits_of(kind).kind for kind in KINDS] == list(KINDS)
    with pytest.raises(
        ValueError, match="unknown vehicle kind 'hovercraft': one of aerial, ground"
    ):
        limits_of("hovercraft")


def test_an_aerial_vehicle_flies_above_ground_only() -> None:
    assert limit_problems(AERIAL, min_altitude_m=0, max_altitude_m=120, max_speed_mps=15) == {}
    problems = limit_problems(AERIAL, min_altitude_m=-5, max_altitude_m=120, max_speed_mps=15)
    assert problems == {"min_altitude_m": "an aerial vehicle goes no lower than 0 m"}


@pytest.mark.parametrize("kind", [GROUND, SURFACE])
def test_ground_and_surface_vehicles_never_climb(kind: str) -> None:
    assert limit_problems(kind, min_altitude_m=0, max_altitude_m=0, max_speed_mps=5) == {}
    problems = limit_problems(kind, min_altitude_m=0, max_altitude_m=10, max_speed_mps=5)
    assert problems["max_altitude_m"].endswith("it moves in the plane and never climbs")
    assert "min_altitude_m" in limit_problems(
        kind, min_altitude_m=-2, max_altitude_m=0, max_speed_mps=5
    )


def test_an_underwater_vehicle_dives_but_does_not_fly_and_moves_slowly() -> None:
    assert limit_problems(UNDERWATER, min_altitude_m=-30, max_altitude_m=0, max_speed_mps=2) == {}
    problems = limit_problems(UNDERWATER, min_altitude_m=-500, max_altitude_m=5, max_speed_mps=12)
    assert problems == {
        "min_altitude_m": "an underwater vehicle goes no lower than -300 m (below 0 is depth)",
        "max_altitude_m": "an underwater vehicle goes no higher than 0 m",
        "max_speed_mps": "an underwater vehicle moves at 10 m/s at most",
    }


@pytest.mark.django_db
def test_a_vehicle_is_validated_by_its_kind() -> None:
    sub = Vehicle(
        name="sub-1",
        kind=UNDERWATER,
        depot_lat=0.005,
        depot_lng=0.005,
        area=SQUARE,
        min_altitude_m=-30,
        max_altitude_m=0,
        max_speed_mps=2,
        dive_rate_mps=0.5,
    )
    sub.full_clean()
    rover = Vehicle(
        name="rover-1",
        kind=GROUND,
        depot_lat=0.005,
        depot_lng=0.005,
        area=SQUARE,
        min_altitude_m=0,
        max_altitude_m=20,
        max_speed_mps=5,
    )
    with pytest.raises(ValidationError) as caught:
        rover.full_clean()
    assert "never climbs" in caught.value.message_dict["max_altitude_m"][0]
    assert Vehicle(name="x", depot_lat=0, depot_lng=0, area=SQUARE, max_altitude_m=1).kind == AERIAL


def test_a_vehicle_that_does_not_fly_is_at_home_at_ground_or_water_level() -> None:
    assert (
        limit_problems(AERIAL, min_altitude_m=0, max_altitude_m=50, max_speed_mps=5, depot_alt_m=12)
        == {}
    )
    problems = limit_problems(
        SURFACE, min_altitude_m=0, max_altitude_m=0, max_speed_mps=5, depot_alt_m=3
    )
    assert problems == {
        "depot_alt": "a surface vehicle's home is at 0 m (it parks or docks at ground or water level)"
    }


@pytest.mark.django_db
def test_rates_belong_to_the_kinds_that_use_them() -> None:
    copter = Vehicle(
        name="c",
        depot_lat=0.005,
        depot_lng=0.005,
        area=SQUARE,
        max_altitude_m=50,
        max_speed_mps=5,
        dive_rate_mps=1.0,
        turn_rate_dps=30,
    )
    with pytest.raises(ValidationError) as caught:
        copter.full_clean()
    assert caught.value.message_dict == {
        "dive_rate_mps": ["only an underwater vehicle dives"],
        "turn_rate_dps": ["only ground and surface vehicles turn in place"],
    }
