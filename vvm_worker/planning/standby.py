"""Where an idle vehicle waits for its next task.

Pure Python (shapely, no Django). With tasks spread over a vehicle's operation area, the point
from which the next one is reached soonest on average is the middle of the area, not its depot
(which may be at a corner, or on the ground: a take-off costs a climb). A vehicle whose planner
`stands_by` waits there, in the air, for a while before it flies home.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence

from shapely.geometry import Point, Polygon
from shapely.ops import nearest_points

from fleet.geo import Position

STANDBY_S = 120.0
"""How long an idle vehicle waits in the air before it flies home (battery permitting)."""


def standby_position(
    area: Polygon,
    recent_altitudes_m: Sequence[float],
    *,
    min_altitude_m: float,
    max_altitude_m: float,
    floor_m: float = 5.0,
) -> Position:
    """The centre of `area` (its centroid, or the nearest point of the area when the centroid
    lies outside, as for an L-shaped area), at the median altitude of the tasks served lately
    (`recent_altitudes_m`; midway between the limits when there are none), kept within the
    vehicle's altitude limits and at least `floor_m` up. `area` is in (lng, lat) coordinates."""
    centre = area.centroid
    if not area.covers(centre):
        centre = nearest_points(area, centre)[0]
    assert isinstance(centre, Point)
    if recent_altitudes_m:
        alt = statistics.median(recent_altitudes_m)
    else:
        alt = (min_altitude_m + max_altitude_m) / 2.0
    alt = min(max(alt, min_altitude_m, floor_m), max_altitude_m)
    return Position(float(centre.y), float(centre.x), alt)
