"""Where the platform can serve a task: the operation areas of the vehicles in service, merged
per altitude band, without saying which vehicle flies where (customers never learn which
vehicles exist).

Pure Python (no Django): the selector ``fleet.selectors.service_area`` reads the vehicles and
the no-fly zones and hands them here.

The vehicles' altitude ranges overlap in any way (one flies 0-120 m over the whole field,
another 20-60 m over a corner), so the bands are the pieces between every range's bounds:
band by band, from the lowest bound up, the union of the areas of the vehicles whose range
spans the whole band. Neighbouring bands over the same ground are one band. At a point and an
altitude a task may be served when a band over that point holds the altitude (bounds
included, as the vehicle mapper decides) and no no-fly zone holds the point at that altitude.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import shapely
from shapely.geometry import Polygon, mapping
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient


@dataclass(frozen=True)
class Reach:
    """Where one vehicle may serve: its operation area ((lng, lat) coordinates) between two
    altitudes (metres above ground)."""

    area: Polygon
    min_altitude_m: float
    max_altitude_m: float


@dataclass(frozen=True)
class Band:
    """Ground where some vehicle in service may serve every altitude from ``min_altitude_m``
    to ``max_altitude_m``."""

    area: BaseGeometry  # a Polygon or MultiPolygon, (lng, lat)
    min_altitude_m: float
    max_altitude_m: float


@dataclass(frozen=True)
class Exclusion:
    """A no-fly zone: no task is served inside ``area`` between the altitudes (None: no
    ceiling)."""

    area: Polygon
    min_altitude_m: float
    max_altitude_m: float | None


def service_bands(reaches: Sequence[Reach]) -> list[Band]:
    """The service area as bands of altitude, lowest first (see the module's docstring).
    Bands with no ground are left out; an empty fleet has none."""
    bounds = sorted({r.min_altitude_m for r in reaches} | {r.max_altitude_m for r in reaches})
    bands: list[Band] = []
    for low, high in itertools.pairwise(bounds):
        spanning = [
            _valid(r.area) for r in reaches if r.min_altitude_m <= low and high <= r.max_altitude_m
        ]
        if not spanning:
            continue
        ground = shapely.unary_union(spanning)
        if ground.is_empty:
            continue
        last = bands[-1] if bands else None
        if last is not None and last.max_altitude_m == low and last.area.equals(ground):
            bands[-1] = Band(last.area, last.min_altitude_m, high)
        else:
            bands.append(Band(ground, low, high))
    # A vehicle allowed at one altitude only (its range a single value) adds no band above:
    # its ground still counts at that altitude.
    for r in reaches:
        if r.min_altitude_m == r.max_altitude_m and not any(
            b.min_altitude_m <= r.min_altitude_m <= b.max_altitude_m
            and b.area.covers(_valid(r.area))
            for b in bands
        ):
            bands.append(Band(_valid(r.area), r.min_altitude_m, r.max_altitude_m))
    return sorted(bands, key=lambda b: (b.min_altitude_m, b.max_altitude_m))


def service_area_geojson(
    reaches: Sequence[Reach], exclusions: Sequence[Exclusion]
) -> dict[str, Any]:
    """The service area as a GeoJSON ``FeatureCollection`` (RFC 7946: [lng, lat], outer rings
    counter-clockwise): one feature per band (``properties``: ``kind`` "service",
    ``min_altitude_m``, ``max_altitude_m``), then one per no-fly zone (``kind`` "no_fly",
    ``max_altitude_m`` null for no ceiling). Nothing names a vehicle."""
    features = [
        _feature(band.area, "service", band.min_altitude_m, band.max_altitude_m)
        for band in service_bands(reaches)
    ]
    features += [
        _feature(_valid(zone.area), "no_fly", zone.min_altitude_m, zone.max_altitude_m)
        for zone in exclusions
    ]
    return {"type": "FeatureCollection", "features": features}


def _valid(area: Polygon) -> BaseGeometry:
    # The areas are checked when they are saved; a union must not fail on one that was not.
    return area if area.is_valid else shapely.make_valid(area)


def _feature(area: BaseGeometry, kind: str, low: float, high: float | None) -> dict[str, Any]:
    return {
        "type": "Feature",
        "geometry": mapping(_oriented(area)),
        "properties": {"kind": kind, "min_altitude_m": low, "max_altitude_m": high},
    }


def _oriented(area: BaseGeometry) -> BaseGeometry:
    """Outer rings counter-clockwise, holes clockwise (RFC 7946, section 3.1.6)."""
    if isinstance(area, Polygon):
        return orient(area, 1.0)
    if area.geom_type == "MultiPolygon":
        return shapely.MultiPolygon([orient(p, 1.0) for p in area.geoms])
    # What make_valid can leave of a degenerate ring (lines, points): only the polygons.
    polygons = [g for g in getattr(area, "geoms", []) if isinstance(g, Polygon)]
    return shapely.MultiPolygon([orient(p, 1.0) for p in polygons])
