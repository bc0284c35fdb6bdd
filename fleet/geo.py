"""Geodesy for the platform: positions, distances and straight-line interpolation.

Pure Python (no Django). Positions are WGS84 degrees with altitude in metres above ground.
Distances are geodesic on the WGS84 ellipsoid (pyproj), with the altitude difference added
as the other leg of a right triangle; at the scale of an operation area this is exact to
well under a centimetre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pyproj import Geod

_GEOD = Geod(ellps="WGS84")


@dataclass(frozen=True, slots=True)
class Position:
    """A point in space: degrees north and east, metres above ground."""

    lat: float
    lng: float
    alt: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lat) and -90.0 <= self.lat <= 90.0):
            raise ValueError(f"latitude {self.lat!r} is outside -90..90")
        if not (math.isfinite(self.lng) and -180.0 <= self.lng <= 180.0):
            raise ValueError(f"longitude {self.lng!r} is outside -180..180")
        if not math.isfinite(self.alt):
            raise ValueError(f"altitude {self.alt!r} is not a finite number")

    def with_alt(self, alt: float) -> Position:
        return Position(self.lat, self.lng, alt)

    def as_list(self) -> list[float]:
        return [self.lat, self.lng, self.alt]


def ground_distance_m(a: Position, b: Position) -> float:
    """Geodesic distance along the ground between two positions, in metres."""
    if a.lat == b.lat and a.lng == b.lng:
        return 0.0
    _, _, dist = _GEOD.inv(a.lng, a.lat, b.lng, b.lat)
    return float(dist)


def headings_deg(a: Position, b: Position) -> tuple[float, float]:
    """The heading (degrees clockwise from north, 0..360) leaving ``a`` for ``b`` along the
    geodesic, and the heading arriving at ``b``."""
    leave, back, _ = _GEOD.inv(a.lng, a.lat, b.lng, b.lat)
    return float(leave) % 360.0, (float(back) + 180.0) % 360.0


def turn_deg(start_deg: float, end_deg: float) -> float:
    """The shortest turn from one heading to another, in degrees (-180..180, + clockwise)."""
    return (end_deg - start_deg + 180.0) % 360.0 - 180.0


def distance_m(a: Position, b: Position) -> float:
    """Straight-line distance in space between two positions, in metres."""
    return math.hypot(ground_distance_m(a, b), b.alt - a.alt)


# Fewer metres than any degree of latitude spans on the ellipsoid (110,574 m at the equator).
_M_PER_DEGREE_LAT_AT_LEAST = 110_000.0


def within_m(a: Position, b: Position, limit_m: float) -> bool:
    """``distance_m(a, b) <= limit_m``, without the geodesic when the difference in latitude
    or altitude alone is more than the limit (most pairs an RV compares are far apart)."""
    if abs(b.alt - a.alt) > limit_m or abs(b.lat - a.lat) * _M_PER_DEGREE_LAT_AT_LEAST > limit_m:
        return False
    return distance_m(a, b) <= limit_m


def interpolate(a: Position, b: Position, fraction: float) -> Position:
    """The point a fraction of the way from a to b (0 gives a, 1 gives b)."""
    if fraction <= 0.0:
        return a
    if fraction >= 1.0:
        return b
    alt = a.alt + (b.alt - a.alt) * fraction
    if a.lat == b.lat and a.lng == b.lng:
        return Position(a.lat, a.lng, alt)
    azimuth, _, dist = _GEOD.inv(a.lng, a.lat, b.lng, b.lat)
    lng, lat, _ = _GEOD.fwd(a.lng, a.lat, azimuth, dist * fraction)
    return Position(float(lat), float(lng), alt)


def offset(origin: Position, *, north_m: float, east_m: float, up_m: float = 0.0) -> Position:
    """The position north_m metres north and east_m metres east of origin (small offsets)."""
    dist = math.hypot(north_m, east_m)
    alt = origin.alt + up_m
    if dist == 0.0:
        return Position(origin.lat, origin.lng, alt)
    azimuth = math.degrees(math.atan2(east_m, north_m))
    lng, lat, _ = _GEOD.fwd(origin.lng, origin.lat, azimuth, dist)
    return Position(float(lat), float(lng), alt)
