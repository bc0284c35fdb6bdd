"""Vehicle kinds: aerial (a copter), ground (a rover), surface (a boat) and underwater (a sub),
and what each may be configured to do.

Pure Python (no Django): the model's validation, scenario files, the simulator and the mapper
read it. Altitudes are metres above the vehicle's home (ground or water level); below zero is
depth, which only an underwater vehicle reaches. Ground and surface vehicles move in the plane:
their altitude is always 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

AERIAL = "aerial"
GROUND = "ground"
SURFACE = "surface"
UNDERWATER = "underwater"
KINDS: tuple[str, ...] = (AERIAL, GROUND, SURFACE, UNDERWATER)
DEFAULT_KIND = AERIAL


@dataclass(frozen=True)
class KindLimits:
    """What a vehicle of one kind can be configured to do.

    ``lowest_m``/``highest_m``: the band its altitude range must lie in (None: no bound).
    ``max_speed_mps``: the fastest it may be set to move. ``vertical``: it changes altitude
    (aerial and underwater); the others stay at 0. ``turn_rate_dps``: how fast it turns in
    place by default (ground and surface vehicles turn before each straight leg; None: it
    turns as it moves, at no cost).
    """

    kind: str
    lowest_m: float | None
    highest_m: float | None
    max_speed_mps: float
    vertical: bool
    turn_rate_dps: float | None = None


LIMITS: dict[str, KindLimits] = {
    AERIAL: KindLimits(AERIAL, lowest_m=0.0, highest_m=None, max_speed_mps=50.0, vertical=True),
    GROUND: KindLimits(
        GROUND, lowest_m=0.0, highest_m=0.0, max_speed_mps=30.0, vertical=False, turn_rate_dps=90.0
    ),
    SURFACE: KindLimits(
        SURFACE, lowest_m=0.0, highest_m=0.0, max_speed_mps=20.0, vertical=False, turn_rate_dps=30.0
    ),
    UNDERWATER: KindLimits(
        UNDERWATER, lowest_m=-300.0, highest_m=0.0, max_speed_mps=10.0, vertical=True
    ),
}


def a_vehicle(kind: str) -> str:
    """ "an aerial vehicle", "a ground vehicle": a kind in an error message."""
    return f"{'an' if kind[:1] in 'aeiou' else 'a'} {kind} vehicle"


def limits_of(kind: str) -> KindLimits:
    """The limits of a kind; ValueError naming the kinds there are when it is not one."""
    try:
        return LIMITS[kind]
    except (KeyError, TypeError):
        raise ValueError(f"unknown vehicle kind {kind!r}: one of {', '.join(KINDS)}") from None


def limit_problems(
    kind: str,
    *,
    min_altitude_m: float,
    max_altitude_m: float,
    max_speed_mps: float,
    depot_alt_m: float = 0.0,
) -> dict[str, str]:
    """What is wrong with a vehicle's configuration for its kind, by field name ({} when
    nothing is): its altitude range must lie in the kind's band, its speed under the kind's
    cap, and the home of a vehicle that is not aerial at 0 m (ground or water level, where it
    parks or docks). Raises ValueError for an unknown kind."""
    limits = limits_of(kind)
    problems: dict[str, str] = {}
    if kind != AERIAL and depot_alt_m != 0:
        problems["depot_alt"] = (
            f"{a_vehicle(kind)}'s home is at 0 m (it parks or docks at ground or water level)"
        )
    if limits.lowest_m is not None and min_altitude_m < limits.lowest_m:
        problems["min_altitude_m"] = (
            f"{a_vehicle(kind)} goes no lower than "
            f"{limits.lowest_m:g} m" + (" (below 0 is depth)" if limits.lowest_m < 0 else "")
        )
    if limits.highest_m is not None and max_altitude_m > limits.highest_m:
        problems["max_altitude_m"] = (
            f"{a_vehicle(kind)} goes no higher than "
            f"{limits.highest_m:g} m"
            + ("" if limits.vertical else ": it moves in the plane and never climbs")
        )
    if math.isfinite(max_speed_mps) and max_speed_mps > limits.max_speed_mps:
        problems["max_speed_mps"] = (
            f"{a_vehicle(kind)} moves at {limits.max_speed_mps:g} m/s at most"
        )
    return problems
