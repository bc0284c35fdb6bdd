"""The provider's no-fly zones and the ways around them.

Pure Python (no Django). A zone is a polygon with an altitude band; a straight leg whose
altitudes overlap the band may not pass within ``clearance_m / 2`` of the polygon. `Airspace.way`
finds the shortest way between two positions that keeps clear of every zone on its altitudes:
the straight leg when nothing is in the way, else a polyline through turn points placed
``clearance_m`` outside the zones' corners (the shortest path in the visibility graph of those
corners, which is the shortest path around polygons). Altitude changes evenly along the way,
as a straight leg's does, so the legs of a way overlap the same bands as the straight leg.

Geometry is computed in metres on an azimuthal equidistant projection centred on the zones,
exact to well under a metre at the scale of an operation area.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import shapely
from numpy.typing import NDArray
from pyproj import Transformer
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

from fleet.geo import Position

CLEARANCE_M = 10.0
"""How far outside a zone's corners a way turns; a leg passes no nearer than half of it."""


class Located(Protocol):
    """Anything with a position's coordinates (a `Position`, a task request)."""

    @property
    def lat(self) -> float: ...
    @property
    def lng(self) -> float: ...
    @property
    def alt(self) -> float: ...


@dataclass(frozen=True)
class ExclusionZone:
    """A no-fly zone: no RV serves a point inside ``area`` ((lng, lat) coordinates, border
    included) between ``min_altitude_m`` and ``max_altitude_m`` (None: no ceiling), and no RV
    flies through it there."""

    area: Polygon
    min_altitude_m: float = 0.0
    max_altitude_m: float | None = None

    def holds(self, point: Located) -> bool:
        """Whether the point lies inside the zone (border included) within its band."""
        return self.spans(point.alt, point.alt) and bool(
            self.area.covers(Point(point.lng, point.lat))
        )

    def spans(self, low_m: float, high_m: float) -> bool:
        """Whether the band overlaps the altitudes from ``low_m`` to ``high_m``."""
        return self.min_altitude_m <= high_m and (
            self.max_altitude_m is None or low_m <= self.max_altitude_m
        )


FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class _Graph:
    """The turn points of a set of zones and which of them see each other."""

    nodes: FloatArray  # (n, 2) projected x, y
    lengths: FloatArray  # (n, n) metres between nodes that see each other, inf otherwise


class Airspace:
    """The no-fly zones of the platform, and the ways around them (see the module's notes).

    Immutable once made; a new set of zones is a new `Airspace`. Ways and graphs are cached
    per set of zones a leg's altitudes meet.
    """

    def __init__(self, zones: Sequence[ExclusionZone], *, clearance_m: float = CLEARANCE_M):
        if not (math.isfinite(clearance_m) and clearance_m > 0.0):
            raise ValueError(f"clearance_m must be a positive finite number, got {clearance_m!r}")
        self.zones = tuple(zones)
        self.clearance_m = clearance_m
        self._graphs: dict[frozenset[int], _Graph] = {}
        if not self.zones:
            return
        lng0, lat0 = _centre(self.zones)
        aeqd = f"+proj=aeqd +lat_0={lat0} +lon_0={lng0} +datum=WGS84 +units=m"
        self._to_xy = Transformer.from_crs("EPSG:4326", aeqd, always_xy=True)
        self._to_lnglat = Transformer.from_crs(aeqd, "EPSG:4326", always_xy=True)
        self._shapes: list[Polygon] = []
        self._walls: list[BaseGeometry] = []  # the zones grown by half the clearance
        self._rings: list[FloatArray] = []  # turn points: the zones' corners, grown
        # Each wall's bounds in degrees (west, south, east, north), a little larger: a leg
        # outside them keeps clear without geometry.
        self._boxes: list[tuple[float, float, float, float]] = []
        for zone in self.zones:
            lng, lat = zone.area.exterior.coords.xy
            x, y = self._to_xy.transform(np.asarray(lng), np.asarray(lat))
            shape = Polygon(np.column_stack([x, y]))
            wall = shape.buffer(clearance_m / 2.0, join_style="mitre", mitre_limit=3.0)
            grown = shape.buffer(clearance_m, join_style="mitre", mitre_limit=3.0)
            shapely.prepare(shape)
            shapely.prepare(wall)
            self._shapes.append(shape)
            self._walls.append(wall)
            ring = np.asarray(grown.exterior.coords, dtype=np.float64)[:-1]  # no closing repeat
            self._rings.append(ring)
            glng, glat = self._to_lnglat.transform(ring[:, 0], ring[:, 1])
            pad = 1e-5  # about a metre
            self._boxes.append(
                (glng.min() - pad, glat.min() - pad, glng.max() + pad, glat.max() + pad)
            )

    def __bool__(self) -> bool:
        return bool(self.zones)

    def __repr__(self) -> str:
        return f"Airspace({len(self.zones)} zones, clearance {self.clearance_m:g} m)"

    def holds(self, point: Located) -> bool:
        """Whether the point lies inside a zone within its band."""
        return any(zone.holds(point) for zone in self.zones)

    def way(self, start: Position, end: Position) -> list[Position] | None:
        """The points to fly through from ``start`` to ``end``, ``end`` last: ``[end]`` when the
        straight leg keeps clear of the zones, the turn points and then ``end`` when it does
        not, None when no way keeps clear (``end`` walled in). A zone that holds ``start`` or
        ``end`` does not count for the legs from or to it (a vehicle inside leaves it)."""
        if not self.zones or (start.lat == end.lat and start.lng == end.lng):
            return [end]
        low, high = min(start.alt, end.alt), max(start.alt, end.alt)
        west, east = min(start.lng, end.lng), max(start.lng, end.lng)
        south, north = min(start.lat, end.lat), max(start.lat, end.lat)
        active = frozenset(k for k, z in enumerate(self.zones) if z.spans(low, high))
        near = [
            k
            for k in sorted(active)
            if west <= self._boxes[k][2]
            and east >= self._boxes[k][0]
            and south <= self._boxes[k][3]
            and north >= self._boxes[k][1]
        ]
        if not near:
            return [end]
        a, b = self._xy(start), self._xy(end)
        segment = LineString([a, b])
        ends = (Point(a), Point(b))
        if not any(self._bars(k, ends).intersects(segment) for k in near):
            return [end]
        # The way round may meet any zone on these altitudes, not only those near the leg.
        graph = self._graph(active)
        order = self._shortest(graph, active, a, b, ends)
        if order is None:
            return None
        return self._positions(graph, order, a, b, start, end)

    def near_pairs(self, positions: Sequence[Position]) -> list[tuple[int, int]]:
        """The pairs (i < j) of positions whose straight leg passes near a zone on its
        altitudes: every pair `way` does not fly straight, and some it does (an end close to a
        zone). Vectorised, for the planners' cost matrices: a bounding-box test first, then
        one geometric test per pair close to a zone."""
        n = len(positions)
        if not self.zones or n < 2:
            return []
        lng = np.fromiter((p.lng for p in positions), dtype=np.float64, count=n)
        lat = np.fromiter((p.lat for p in positions), dtype=np.float64, count=n)
        alt = np.fromiter((p.alt for p in positions), dtype=np.float64, count=n)
        x, y = self._to_xy.transform(lng, lat)
        i, j = np.triu_indices(n, k=1)
        found: set[tuple[int, int]] = set()
        for k, zone in enumerate(self.zones):
            x0, y0, x1, y1 = self._walls[k].bounds
            low, high = np.minimum(alt[i], alt[j]), np.maximum(alt[i], alt[j])
            near = (
                (np.minimum(x[i], x[j]) <= x1)
                & (np.maximum(x[i], x[j]) >= x0)
                & (np.minimum(y[i], y[j]) <= y1)
                & (np.maximum(y[i], y[j]) >= y0)
                & (high >= zone.min_altitude_m)
            )
            if zone.max_altitude_m is not None:
                near &= low <= zone.max_altitude_m
            ci, cj = i[near], j[near]
            if ci.size == 0:
                continue
            lines = shapely.linestrings(
                np.stack([np.column_stack([x[ci], y[ci]]), np.column_stack([x[cj], y[cj]])], axis=1)
            )
            hit = shapely.intersects(self._walls[k], lines)
            found.update(zip(ci[hit].tolist(), cj[hit].tolist(), strict=True))
        return sorted(found)

    # --- geometry ------------------------------------------------------------------------------

    def _xy(self, p: Position) -> tuple[float, float]:
        x, y = self._to_xy.transform(p.lng, p.lat)
        return float(x), float(y)

    def _bars(self, k: int, ends: Sequence[Point]) -> BaseGeometry:
        """What zone k bars a leg from or to ``ends``: its wall, the zone itself when an end
        is within the wall (a task close to a zone), nothing when an end is inside it."""
        shape, wall = self._shapes[k], self._walls[k]
        if any(shape.covers(e) for e in ends):
            return Polygon()
        if any(wall.covers(e) for e in ends):
            return shape
        return wall

    def _graph(self, active: frozenset[int]) -> _Graph:
        graph = self._graphs.get(active)
        if graph is not None:
            return graph
        walls = shapely.union_all([self._walls[k] for k in sorted(active)])
        shapely.prepare(walls)
        points = np.concatenate([self._rings[k] for k in sorted(active)])
        # A turn point inside another zone's wall is no way round.
        points = points[~shapely.intersects(walls, shapely.points(points))]
        n = len(points)
        lengths = np.full((n, n), np.inf)
        if n:
            i, j = np.triu_indices(n, k=1)
            lines = shapely.linestrings(np.stack([points[i], points[j]], axis=1))
            clear = ~shapely.intersects(walls, lines)
            d = np.hypot(*(points[i[clear]] - points[j[clear]]).T)
            lengths[i[clear], j[clear]] = d
            lengths[j[clear], i[clear]] = d
        graph = _Graph(points, lengths)
        self._graphs[active] = graph
        return graph

    def _sight(
        self,
        active: frozenset[int],
        origin: tuple[float, float],
        ends: Sequence[Point],
        to: FloatArray,
    ) -> FloatArray:
        """Metres from ``origin`` to each point of ``to`` it sees (inf where it does not)."""
        if len(to) == 0:
            return np.zeros(0)
        bars = shapely.union_all([self._bars(k, ends) for k in sorted(active)])
        lines = shapely.linestrings(np.stack([np.broadcast_to(origin, to.shape), to], axis=1))
        seen = ~shapely.intersects(bars, lines)
        return np.where(seen, np.hypot(to[:, 0] - origin[0], to[:, 1] - origin[1]), np.inf)

    def _shortest(
        self,
        graph: _Graph,
        active: frozenset[int],
        a: tuple[float, float],
        b: tuple[float, float],
        ends: Sequence[Point],
    ) -> list[int] | None:
        """The turn points (indices into ``graph.nodes``) of the shortest way from a to b,
        by Dijkstra over the visibility graph; None when b cannot be reached."""
        from_a = self._sight(active, a, ends[:1], graph.nodes)
        to_b = self._sight(active, b, ends[1:], graph.nodes)
        n = len(graph.nodes)
        best = from_a.copy()
        previous = np.full(n, -1)
        done = np.zeros(n, dtype=bool)
        queue = [(float(d), k) for k, d in enumerate(best) if math.isfinite(d)]
        heapq.heapify(queue)
        while queue:
            d, k = heapq.heappop(queue)
            if done[k]:
                continue
            done[k] = True
            through = d + graph.lengths[k]
            better = (through < best) & ~done
            for m in np.flatnonzero(better).tolist():
                best[m] = through[m]
                previous[m] = k
                heapq.heappush(queue, (float(through[m]), m))
        total = best + to_b
        last = int(np.argmin(total)) if n else -1
        if last < 0 or not math.isfinite(total[last]):
            return None
        order = [last]
        while previous[order[-1]] >= 0:
            order.append(int(previous[order[-1]]))
        return order[::-1]

    def _positions(
        self,
        graph: _Graph,
        order: list[int],
        a: tuple[float, float],
        b: tuple[float, float],
        start: Position,
        end: Position,
    ) -> list[Position]:
        points = np.vstack([[a], graph.nodes[order], [b]])
        legs = np.hypot(*np.diff(points, axis=0).T)
        along = np.cumsum(legs)[:-1] / legs.sum()
        lng, lat = self._to_lnglat.transform(graph.nodes[order, 0], graph.nodes[order, 1])
        turns = [
            Position(float(la), float(ln), start.alt + (end.alt - start.alt) * float(f))
            for la, ln, f in zip(np.atleast_1d(lat), np.atleast_1d(lng), along, strict=True)
        ]
        return [*turns, end]


NO_ZONES = Airspace(())
"""The airspace without zones: every way is straight."""


def _centre(zones: Sequence[ExclusionZone]) -> tuple[float, float]:
    x0, y0, x1, y1 = shapely.union_all([z.area for z in zones]).bounds
    return (x0 + x1) / 2.0, (y0 + y1) / 2.0
