"""Distances the RVs compare at every arrival: the quick test says what the geodesic says."""

from __future__ import annotations

import random

from fleet.geo import Position, distance_m, within_m


def test_within_agrees_with_the_distance_near_and_far_at_every_latitude() -> None:
    rng = random.Random(7)
    for _ in range(4000):
        a = Position(rng.uniform(-85, 85), rng.uniform(-180, 180), rng.uniform(0, 120))
        # Near (a few metres, where the limit decides) and far (where the quick test does).
        scale = rng.choice([1e-6, 1e-5, 1e-4, 1e-2])
        b = Position(
            a.lat + rng.uniform(-1, 1) * scale,
            a.lng + rng.uniform(-1, 1) * scale,
            a.alt + rng.uniform(-5, 5),
        )
        limit = rng.uniform(0.5, 20.0)
        assert within_m(a, b, limit) == (distance_m(a, b) <= limit), (a, b, limit)


def test_a_point_just_inside_or_outside_the_limit_in_latitude() -> None:
    a = Position(0.0, 10.0, 50.0)  # at the equator a degree of latitude is 110,574 m
    inside = Position(0.0 + 5.0 / 110_574, 10.0, 50.0)  # about 5 m north
    assert within_m(a, inside, 5.01) and not within_m(a, inside, 4.99)
    assert not within_m(a, Position(0.0, 10.0, 56.0), 5.0)  # 6 m above
