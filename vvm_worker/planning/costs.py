"""Cost matrices for the planners: node 0 is the vehicle's position, nodes 1..n the tasks.

The planners only ever call the cost function through this module, so the rules about it live
in one place: costs must be finite and not negative, and the default `fleet.geo.distance_m` has
a vectorised fast path for large task sets, because one geodesic per pair (about 1 µs each)
would take a second for 1,000 tasks.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleet.airspace import Airspace
from fleet.geo import Position, distance_m
from fleet.kinematics import leg_s, legs_s

from .base import CostFn

FloatArray = NDArray[np.float64]

EXACT_DEFAULT_LIMIT = 64
"""Up to this many tasks the default cost is evaluated pair by pair with `distance_m` itself;
above it, task-to-task distances come from the vectorised approximation below."""

# WGS84, as fleet.geo uses through pyproj.
_WGS84_A = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)


@dataclass(frozen=True, slots=True)
class CostMatrix:
    """Travel costs between the vehicle (node 0) and the tasks (nodes 1..n).

    `values[i, j]` is the cost from node i to node j. Column 0 is 0: no path returns to the
    vehicle's position. `symmetric` says whether the task-to-task block is symmetric, which
    decides whether reversing part of a path leaves its cost unchanged.
    """

    values: FloatArray
    symmetric: bool

    @property
    def size(self) -> int:
        """Number of nodes, tasks plus the vehicle."""
        return int(self.values.shape[0])


@dataclass(frozen=True, slots=True)
class TravelTime:
    """Seconds a vehicle needs to fly straight from one position to another: it cruises at
    `max_speed_mps` while climbing at `climb_rate_mps` or descending at `dive_rate_mps` (None:
    the climb rate), so a leg lasts max(ground distance / speed, height difference / rate), as
    `fleet.simulation` flies it. A cost function with a vectorised fast path in
    `build_cost_matrix`; symmetric unless the two rates differ (an underwater vehicle that
    dives slower than it rises). A ground or surface vehicle's turns in place before each leg
    are not counted: they depend on the heading it arrives with, which a cost between two
    positions does not know, so its costs are estimates on the low side.
    Raises ValueError when a rate is not a positive finite number.
    """

    max_speed_mps: float
    climb_rate_mps: float = 3.0
    dive_rate_mps: float | None = None

    def __post_init__(self) -> None:
        for name in ("max_speed_mps", "climb_rate_mps", "dive_rate_mps"):
            value = getattr(self, name)
            if value is None and name == "dive_rate_mps":
                continue
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")

    @property
    def descent_rate_mps(self) -> float:
        """Vertical speed going down: the dive rate, else the climb rate."""
        return self.climb_rate_mps if self.dive_rate_mps is None else self.dive_rate_mps

    @property
    def symmetric(self) -> bool:
        """Whether a leg costs the same both ways (it does unless the rates differ)."""
        return self.descent_rate_mps == self.climb_rate_mps

    def __call__(self, a: Position, b: Position) -> float:
        return leg_s(
            a,
            b,
            speed_mps=self.max_speed_mps,
            climb_mps=self.climb_rate_mps,
            descent_mps=self.descent_rate_mps,
        )


NO_WAY_COST = 1e9
"""The cost of a leg no way around the no-fly zones makes (finite, as costs must be): the
planners put such a task last, and the vehicle that gets there fails it."""

# Legs `AroundZones` remembers; a vehicle re-plans over mostly the same tasks.
_WAYS_KEPT = 50_000


@dataclass(frozen=True)
class AroundZones:
    """A cost along the way around the no-fly zones (`Airspace.way`): the `inner` cost (a
    straight leg's: `distance_m`, `TravelTime`) summed over the way's legs, `NO_WAY_COST`
    where there is no way. The way's altitude changes evenly, so for `TravelTime` the sum is
    what flying it takes. Legs near a zone are remembered (the way costs a graph search)."""

    inner: CostFn
    airspace: Airspace
    _kept: dict[tuple[Position, Position], float] = field(
        default_factory=dict, compare=False, hash=False, repr=False
    )

    def __call__(self, a: Position, b: Position) -> float:
        known = self._kept.get((a, b))
        if known is not None:
            return known
        way = self.airspace.way(a, b)
        if way is None:
            value = NO_WAY_COST
        elif len(way) == 1:
            return self.inner(a, b)
        else:
            value = sum(self.inner(p, q) for p, q in itertools.pairwise([a, *way]))
        if len(self._kept) >= _WAYS_KEPT:
            self._kept.clear()
        self._kept[(a, b)] = value
        return value


def _exact_block(
    cost: CostFn,
    positions: Sequence[Position],
    values: FloatArray,
    known: TaskCosts | None,
    *,
    symmetric: bool = True,
) -> None:
    """The task block of `values`, one call of `cost` per unordered pair not `known` (per
    ordered pair when the cost is not `symmetric`)."""
    n = len(positions)
    old = [-1] * n if known is None else [known.index.get(p, -1) for p in positions]
    seen = [k for k in range(n) if old[k] >= 0]
    if len(seen) > 1 and known is not None:
        at = np.array([old[k] for k in seen])
        rows = np.array(seen) + 1
        values[np.ix_(rows, rows)] = known.block[np.ix_(at, at)]
    for i in range(n):
        for j in range(i + 1, n):
            if (old[i] < 0 or old[j] < 0) and not symmetric:
                values[i + 1, j + 1] = cost(positions[i], positions[j])
                values[j + 1, i + 1] = cost(positions[j], positions[i])
            elif old[i] < 0 or old[j] < 0:
                # Symmetric in theory; mirroring keeps the matrix exactly so.
                values[i + 1, j + 1] = values[j + 1, i + 1] = cost(positions[i], positions[j])
    if known is not None:
        known.keep(positions, values[1:, 1:].copy())


def costs_from(cost: CostFn, origin: Position, positions: Sequence[Position]) -> FloatArray:
    """The cost from `origin` to each position, one call of `cost` per position.

    Raises ValueError when the cost function returns a negative or non-finite value.
    """
    values = np.fromiter(
        (cost(origin, p) for p in positions), dtype=np.float64, count=len(positions)
    )
    _check_values(values, lambda k: (origin, positions[k]))
    return values


class TaskCosts:
    """The task block of the last matrix `build_cost_matrix` built for one planner, by
    position: a vehicle re-plans over mostly the same tasks (one served, one new), so the next
    matrix copies the pairs it already knows instead of computing them again. Only for the
    default costs, which depend on the two positions alone: the values are the same."""

    def __init__(self) -> None:
        self.index: dict[Position, int] = {}
        self.block: FloatArray = np.zeros((0, 0), dtype=np.float64)

    def keep(self, positions: Sequence[Position], block: FloatArray) -> None:
        self.index = {p: k for k, p in enumerate(positions)}
        self.block = block


def build_cost_matrix(
    cost: CostFn,
    origin: Position,
    positions: Sequence[Position],
    *,
    known: TaskCosts | None = None,
) -> CostMatrix:
    """The cost matrix over `origin` followed by `positions`.

    Row 0 always comes from `cost` itself, so the first step of every planner is judged with
    the true cost. The task block calls `cost` once per ordered pair (n * (n - 1) calls) for a
    custom cost; `distance_m` and `TravelTime` are evaluated once per unordered pair (per
    ordered pair for a `TravelTime` that is not symmetric) up to `EXACT_DEFAULT_LIMIT` tasks
    (pairs `known` from the caller's last matrix are copied from it, and it keeps this one),
    and from a vectorised approximation of the ground distance above that (error below 1e-6
    relative for legs under 50 km). Raises ValueError when a cost is negative or not finite.
    """
    if isinstance(cost, AroundZones):
        return _around_zones(cost, origin, positions, known)
    n = len(positions)
    values = np.zeros((n + 1, n + 1), dtype=np.float64)
    values[0, 1:] = costs_from(cost, origin, positions)
    if cost is distance_m or isinstance(cost, TravelTime):
        symmetric = not isinstance(cost, TravelTime) or cost.symmetric
        if n <= EXACT_DEFAULT_LIMIT:
            _exact_block(cost, positions, values, known, symmetric=symmetric)
            return CostMatrix(values, symmetric=symmetric)
        ground = approximate_ground_matrix(positions)
        alt = np.fromiter((p.alt for p in positions), dtype=np.float64, count=n)
        if isinstance(cost, TravelTime):
            values[1:, 1:] = legs_s(
                ground,
                alt,
                speed_mps=cost.max_speed_mps,
                climb_mps=cost.climb_rate_mps,
                descent_mps=cost.descent_rate_mps,
            )
        else:
            dalt = np.abs(alt[:, None] - alt[None, :])
            values[1:, 1:] = np.hypot(ground, dalt, out=ground)
        return CostMatrix(values, symmetric=symmetric)
    block = np.zeros((n, n), dtype=np.float64)
    for i, a in enumerate(positions):
        for j, b in enumerate(positions):
            if i != j:
                block[i, j] = cost(a, b)
    _check_values(block.ravel(), lambda k: (positions[k // n], positions[k % n]))
    scale = float(block.max()) if n else 0.0
    symmetric = bool(np.allclose(block, block.T, rtol=1e-12, atol=1e-12 * scale))
    if symmetric:
        # Rounding-level asymmetry would otherwise make reversal deltas disagree with the
        # cost of the reversed path by a few ulps.
        block = (block + block.T) / 2.0
    values[1:, 1:] = block
    return CostMatrix(values, symmetric=symmetric)


def _around_zones(
    cost: AroundZones, origin: Position, positions: Sequence[Position], known: TaskCosts | None
) -> CostMatrix:
    """The matrix of the straight legs, with the legs that pass near a zone costed along
    their way around it: a way is a graph search, a straight leg a formula (or a copy)."""
    matrix = build_cost_matrix(cost.inner, origin, positions, known=known)
    values = matrix.values
    nodes = [origin, *positions]
    for i, j in cost.airspace.near_pairs(nodes):
        values[i, j] = cost(nodes[i], nodes[j])
        if i > 0:  # nothing returns to the vehicle's position (column 0)
            values[j, i] = values[i, j] if matrix.symmetric else cost(nodes[j], nodes[i])
    return matrix


def approximate_distance_matrix(positions: Sequence[Position]) -> FloatArray:
    """`distance_m` between all pairs of positions, vectorised: the ground distance of
    `approximate_ground_matrix` and the altitude difference are the legs of a right triangle,
    as in `distance_m`. Accurate to about a millimetre over 10 km."""
    ground = approximate_ground_matrix(positions)
    alt = np.fromiter((p.alt for p in positions), dtype=np.float64, count=len(positions))
    dalt = alt[:, None] - alt[None, :]
    result: FloatArray = np.hypot(ground, dalt, out=ground)
    return result


def approximate_ground_matrix(positions: Sequence[Position]) -> FloatArray:
    """`ground_distance_m` between all pairs of positions, vectorised.

    The straight chord between the points on the WGS84 ellipsoid, lengthened by the
    chord-to-arc term c^3 / (24 R^2). Accurate to about a millimetre over 10 km.
    """
    lat = np.radians(np.fromiter((p.lat for p in positions), dtype=np.float64))
    lng = np.radians(np.fromiter((p.lng for p in positions), dtype=np.float64))
    sin_lat = np.sin(lat)
    normal = _WGS84_A / np.sqrt(1.0 - _WGS84_E2 * sin_lat * sin_lat)
    xyz = np.stack(
        [
            normal * np.cos(lat) * np.cos(lng),
            normal * np.cos(lat) * np.sin(lng),
            normal * (1.0 - _WGS84_E2) * sin_lat,
        ],
        axis=1,
    )
    # Centring first keeps the Gram-matrix trick free of cancellation (ECEF norms are 6e6 m).
    xyz -= xyz.mean(axis=0)
    norms = np.einsum("ij,ij->i", xyz, xyz)
    chord_sq = norms[:, None] + norms[None, :] - 2.0 * (xyz @ xyz.T)
    np.maximum(chord_sq, 0.0, out=chord_sq)
    radius = _gaussian_radius(float(np.mean(lat)))
    # In place throughout: at 1,000 tasks every temporary is an 8 MB array.
    ground: FloatArray = np.sqrt(chord_sq)
    chord_sq *= ground
    chord_sq *= 1.0 / (24.0 * radius * radius)
    ground += chord_sq
    np.fill_diagonal(ground, 0.0)
    return ground


def _gaussian_radius(lat_rad: float) -> float:
    """Geometric mean of the ellipsoid's two principal radii of curvature at a latitude."""
    w2 = 1.0 - _WGS84_E2 * math.sin(lat_rad) ** 2
    meridional = _WGS84_A * (1.0 - _WGS84_E2) / w2**1.5
    normal = _WGS84_A / math.sqrt(w2)
    return math.sqrt(meridional * normal)


def _check_values(values: FloatArray, pair_of: Callable[[int], tuple[Position, Position]]) -> None:
    bad = np.flatnonzero(~np.isfinite(values) | (values < 0.0))
    if bad.size:
        k = int(bad[0])
        a, b = pair_of(k)
        raise ValueError(
            f"cost function returned {float(values[k])!r} from {a} to {b}; "
            "costs must be finite and not negative"
        )
