"""The geofence as ArduCopter enforces it: a maximum altitude, a circle around home and the
polygons uploaded with the mission protocol (MAV_MISSION_TYPE_FENCE: inside every inclusion
polygon, outside every exclusion polygon), switched on by FENCE_ENABLE and chosen by
FENCE_TYPE's bits.

``Fence`` answers which fences a position breaches; ``FenceStatus`` is what FENCE_STATUS
reports. What a breach does (FENCE_ACTION) is the vehicle's business (``failsafes.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from shapely import Point, Polygon

from fleet.geo import Position, ground_distance_m
from fleet.mavlink.mission import MissionItem, exclusion_polygons, inclusion_polygons
from fleet.mavlink.wire import mavlink

# FENCE_TYPE's bits (AC_Fence: AC_FENCE_TYPE_ALT_MAX, _CIRCLE, _POLYGON).
ALT_MAX = 1
CIRCLE = 2
POLYGON = 4
# How ArduPilot names them in "Polygon fence breached" (AC_Fence::get_fence_names).
_NAMES = ((ALT_MAX, "Max Alt"), (CIRCLE, "Circle"), (POLYGON, "Polygon"))

# FENCE_ACTION values that land rather than return (ArduCopter: 2 always land, 4 brake or
# land, 5 SmartRTL or land); 0 only reports, the others return to launch.
REPORT_ONLY = 0
LANDING_ACTIONS = frozenset({2, 4, 5})


def fence_names(fences: int) -> str:
    """ArduPilot's words for a set of fences: "Max Alt fence", "Max Alt and Polygon fences"."""
    names = [name for bit, name in _NAMES if fences & bit]
    if not names:
        return ""
    joined = names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
    return joined + (" fences" if len(names) > 1 else " fence")


@dataclass
class FenceStatus:
    """What FENCE_STATUS says: the fences breached now, how often a breach began, the kind and
    boot time (ms) of the last one."""

    breaches: int = 0
    count: int = 0
    breach_type: int = mavlink.FENCE_BREACH_NONE
    time_ms: int = 0

    def update(self, breaches: int, time_ms: int) -> int:
        """Take the fences breached now (``time_ms``: the boot time); returns those newly
        breached, 0 for none (a breach begins: it counts and is timed)."""
        new = breaches & ~self.breaches
        self.breaches = breaches
        self.breach_type = breach_type(breaches)
        if new:
            self.count += 1
            self.time_ms = time_ms
        return new

    def send(self, mav: Any) -> None:
        mav.fence_status_send(1 if self.breaches else 0, self.count, self.breach_type, self.time_ms)


def breach_type(fences: int) -> int:
    """FENCE_STATUS.breach_type for a set of fences (a boundary wins over the altitude, as
    ArduPilot reports it)."""
    if fences & (CIRCLE | POLYGON):
        return int(mavlink.FENCE_BREACH_BOUNDARY)
    if fences & ALT_MAX:
        return int(mavlink.FENCE_BREACH_MAXALT)
    return int(mavlink.FENCE_BREACH_NONE)


class Fence:
    """Which fences a position breaches. ``param`` reads a parameter's value, ``items`` the
    stored fence list (the same list object until the next upload), ``home`` is the circle's
    centre and the altitudes' zero."""

    def __init__(
        self,
        param: Callable[[str], float],
        items: Callable[[], Sequence[MissionItem]],
        home: Position,
    ) -> None:
        self._param = param
        self._items = items
        self.home = home
        self._polygons_of: Sequence[MissionItem] | None = None
        self._inclusions: list[Polygon] = []
        self._exclusions: list[Polygon] = []

    @property
    def enabled(self) -> bool:
        return self._param("FENCE_ENABLE") >= 0.5

    def breaches(self, position: Position) -> int:
        """The FENCE_TYPE bits of the enabled fences ``position`` breaches (0: none, or the
        fence is off). As in ArduPilot, every inclusion polygon must contain it and no
        exclusion polygon may."""
        if not self.enabled:
            return 0
        kinds = round(self._param("FENCE_TYPE"))
        breached = 0
        if kinds & ALT_MAX and position.alt - self.home.alt > self._param("FENCE_ALT_MAX"):
            breached |= ALT_MAX
        if kinds & CIRCLE and ground_distance_m(self.home, position) > self._param("FENCE_RADIUS"):
            breached |= CIRCLE
        if kinds & POLYGON:
            self._load_polygons()
            point = Point(position.lng, position.lat)
            if any(not polygon.covers(point) for polygon in self._inclusions) or any(
                polygon.contains(point) for polygon in self._exclusions
            ):
                breached |= POLYGON
        return breached

    def _load_polygons(self) -> None:
        items = self._items()
        if items is self._polygons_of:
            return
        self._polygons_of = items
        self._inclusions = [_polygon(ring) for ring in inclusion_polygons(items)]
        self._exclusions = [_polygon(ring) for ring in exclusion_polygons(items)]


def _polygon(ring: Sequence[tuple[float, float]]) -> Polygon:
    return Polygon([(lng, lat) for lat, lng in ring])
