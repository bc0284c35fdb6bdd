"""How long a vehicle takes to get somewhere: the platform's one travel-time formula, which the
simulator flies, the MAVLink driver estimates with and the planners cost their routes by.

A straight leg lasts ``max(ground distance / speed, |rise| / rate)``: the vehicle cruises at
its horizontal speed while it climbs at its climb rate (descends at its descent rate), so it
reaches the end horizontally and vertically at once. A vehicle on the ground that flies rises
straight up first (``take_off_top``), to the leg's end or its take-off altitude, whichever is
higher. Turns in place (rovers, boats) depend on a heading and are their users' own.

Pure: no Django, no state.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fleet.geo import Position, ground_distance_m

FloatArray = NDArray[np.float64]


def leg_s(
    start: Position, end: Position, *, speed_mps: float, climb_mps: float, descent_mps: float
) -> float:
    """Seconds of a straight leg from ``start`` to ``end`` (rates in metres per second)."""
    rise = end.alt - start.alt
    rate = climb_mps if rise >= 0.0 else descent_mps
    return max(ground_distance_m(start, end) / speed_mps, abs(rise) / rate)


def legs_s(
    ground_m: FloatArray,
    alt_m: FloatArray,
    *,
    speed_mps: float,
    climb_mps: float,
    descent_mps: float,
) -> FloatArray:
    """``leg_s`` between every two of n positions at once: ``ground_m[i, j]`` the ground
    distance from position i to j (an n x n array, overwritten with the result), ``alt_m``
    their altitudes. Entry [i, j] of the result is the leg from i to j (to a few ulps of
    ``leg_s``: the division is a multiplication by the reciprocal here)."""
    ground_m *= 1.0 / speed_mps
    # rise[i, j]: the climb from position i to position j (below 0: a descent).
    rise = alt_m[None, :] - alt_m[:, None]
    if climb_mps == descent_mps:
        np.abs(rise, out=rise)
        rise *= 1.0 / climb_mps
    else:
        rise = np.where(rise >= 0.0, rise / climb_mps, -rise / descent_mps)
    return np.maximum(ground_m, rise, out=ground_m)


def take_off_top(here: Position, target: Position, *, takeoff_alt_m: float) -> Position:
    """Where a vehicle on the ground at ``here`` ends its vertical take-off towards
    ``target``: straight above ``here`` at the target's altitude or the take-off altitude,
    whichever is higher (``here`` itself when it is that high already)."""
    return here.with_alt(max(target.alt, takeoff_alt_m, here.alt))


def from_ground_s(
    here: Position,
    target: Position,
    *,
    takeoff_alt_m: float,
    speed_mps: float,
    climb_mps: float,
    descent_mps: float,
) -> float:
    """Seconds from the ground at ``here`` to ``target``: the vertical take-off
    (``take_off_top``), then the straight leg."""
    top = take_off_top(here, target, takeoff_alt_m=takeoff_alt_m)
    rates = {"speed_mps": speed_mps, "climb_mps": climb_mps, "descent_mps": descent_mps}
    return leg_s(here, top, **rates) + leg_s(top, target, **rates)
