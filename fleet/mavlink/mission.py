"""Mission items and the geofence as the mission protocol carries it.

A geofence travels over the same protocol as a mission, with ``mission_type`` =
MAV_MISSION_TYPE_FENCE on every message. An inclusion polygon is N consecutive items with
command MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, each carrying the polygon's vertex count N
in param1 and one vertex in x (latitude * 1e7) and y (longitude * 1e7). The polygon is closed
implicitly: the first vertex is not repeated at the end (an operation area's ring is, so
``fence_polygon_items`` drops its closing point).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from fleet.mavlink.wire import mavlink

FENCE_COMMANDS = frozenset(
    {
        mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT,
        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
        mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
        mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
    }
)
_POLYGON_COMMANDS = frozenset(
    {
        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
    }
)


def to_e7(degrees: float) -> int:
    """Degrees as the protocol's integer degrees * 1e7."""
    return round(degrees * 1e7)


@dataclass(frozen=True)
class MissionItem:
    """One item of a mission, fence or rally list, as MISSION_ITEM_INT carries it.

    ``x``/``y`` are latitude/longitude in degrees * 1e7 for global frames; ``z`` an altitude
    in metres. ``seq`` is the item's index in its list.
    """

    command: int
    frame: int = mavlink.MAV_FRAME_GLOBAL
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    seq: int = 0
    current: int = 0
    autocontinue: int = 1

    @property
    def lat(self) -> float:
        return self.x / 1e7

    @property
    def lng(self) -> float:
        return self.y / 1e7

    def with_seq(self, seq: int) -> MissionItem:
        return replace(self, seq=seq)

    @classmethod
    def from_message(cls, msg: Any) -> MissionItem:
        """The item a MISSION_ITEM_INT (or the older MISSION_ITEM, whose x/y are degrees as
        floats) carries."""
        if msg.get_type() == "MISSION_ITEM":
            x, y = round(msg.x * 1e7), round(msg.y * 1e7)
        else:
            x, y = int(msg.x), int(msg.y)
        return cls(
            command=int(msg.command),
            frame=int(msg.frame),
            param1=float(msg.param1),
            param2=float(msg.param2),
            param3=float(msg.param3),
            param4=float(msg.param4),
            x=x,
            y=y,
            z=float(msg.z),
            seq=int(msg.seq),
            current=int(msg.current),
            autocontinue=int(msg.autocontinue),
        )

    def send(self, mav: Any, system: int, component: int, mission_type: int) -> None:
        """Send the item as MISSION_ITEM_INT to ``system``/``component`` with pymavlink's
        ``mav`` (a connection's MAVLink object)."""
        mav.mission_item_int_send(
            system,
            component,
            self.seq,
            self.frame,
            self.command,
            self.current,
            self.autocontinue,
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            self.x,
            self.y,
            self.z,
            mission_type,
        )


def fence_polygon_items(
    ring: Sequence[Sequence[float]], *, exclusion: bool = False, first_seq: int = 0
) -> list[MissionItem]:
    """The fence items of one inclusion polygon (``exclusion``: an exclusion polygon, a zone
    the vehicle must not enter) from a ring of (lat, lng) points.

    A closing point equal to the first is dropped, as are repeated consecutive points.
    Returns the items numbered from ``first_seq``. Raises ValueError for fewer than 3 distinct
    vertices or a coordinate out of range.
    """
    vertices: list[tuple[float, float]] = []
    for point in ring:
        lat, lng = float(point[0]), float(point[1])
        if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
            raise ValueError(f"latitude {lat!r} is outside -90..90")
        if not (math.isfinite(lng) and -180.0 <= lng <= 180.0):
            raise ValueError(f"longitude {lng!r} is outside -180..180")
        if not vertices or vertices[-1] != (lat, lng):
            vertices.append((lat, lng))
    if len(vertices) > 1 and vertices[0] == vertices[-1]:
        vertices.pop()
    if len(set(vertices)) < 3:
        raise ValueError("a fence polygon needs at least 3 distinct vertices")
    count = float(len(vertices))
    command = (
        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
        if exclusion
        else mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
    )
    return [
        MissionItem(command=command, param1=count, x=to_e7(lat), y=to_e7(lng), seq=seq)
        for seq, (lat, lng) in enumerate(vertices, start=first_seq)
    ]


def rally_items(points: Sequence[tuple[float, float, float]]) -> list[MissionItem]:
    """The rally list (MAV_MISSION_TYPE_RALLY) of (lat, lng, altitude above home) points:
    MAV_CMD_NAV_RALLY_POINT items, frame GLOBAL_RELATIVE_ALT_INT."""
    return [
        MissionItem(
            command=mavlink.MAV_CMD_NAV_RALLY_POINT,
            frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            x=to_e7(lat),
            y=to_e7(lng),
            z=float(alt),
            seq=seq,
        )
        for seq, (lat, lng, alt) in enumerate(points)
    ]


def inclusion_polygons(items: Sequence[MissionItem]) -> list[list[tuple[float, float]]]:
    """The inclusion polygons of a fence list, each as its (lat, lng) vertices in order.

    Items are grouped as the protocol says: a polygon is the next param1 vertex items.
    Raises ValueError when a polygon is cut short or its items disagree on the count.
    """
    return _polygons(items, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION)


def exclusion_polygons(items: Sequence[MissionItem]) -> list[list[tuple[float, float]]]:
    """The exclusion polygons of a fence list, as ``inclusion_polygons`` reads those."""
    return _polygons(items, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)


def _polygons(items: Sequence[MissionItem], kind: int) -> list[list[tuple[float, float]]]:
    polygons: list[list[tuple[float, float]]] = []
    i = 0
    while i < len(items):
        item = items[i]
        if item.command not in _POLYGON_COMMANDS:
            i += 1
            continue
        count = int(item.param1)
        group = list(items[i : i + count])
        if count < 3 or len(group) < count:
            raise ValueError(f"fence item {i}: a polygon of {count} vertices is cut short")
        if any(g.command != item.command or int(g.param1) != count for g in group):
            raise ValueError(f"fence items {i}..{i + count - 1} disagree on their polygon")
        if item.command == kind:
            polygons.append([(g.lat, g.lng) for g in group])
        i += count
    return polygons


def validate_fence(items: Sequence[MissionItem]) -> int:
    """Check a fence list as a vehicle would on upload.

    Returns MAV_MISSION_ACCEPTED, or the MAV_MISSION_RESULT that says what is wrong:
    MAV_MISSION_UNSUPPORTED for a command that is not a fence item,
    MAV_MISSION_INVALID_PARAM1 for an inconsistent polygon vertex count.
    """
    if any(item.command not in FENCE_COMMANDS for item in items):
        return int(mavlink.MAV_MISSION_UNSUPPORTED)
    try:
        inclusion_polygons(items)
    except ValueError:
        return int(mavlink.MAV_MISSION_INVALID_PARAM1)
    return int(mavlink.MAV_MISSION_ACCEPTED)
