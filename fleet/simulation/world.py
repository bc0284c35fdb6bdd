"""The seeded procedural world that sensor fields and camera images are drawn from.

Pure Python + numpy (no Django). Everything here is a deterministic function of a seed and
local metric coordinates, defined on the whole plane, so any two samples of the same place
agree and nearby places look related. Noise comes from integer hashing (no global random
state), so results do not depend on call order.

Coordinates: ``local_xy(lat, lng)`` gives metres east (x) and north (y) of (0, 0) on a simple
equirectangular projection; it is only used to place smooth structure, not to measure.
"""

from __future__ import annotations

import hashlib
import math
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

# The seed of the world the platform's simulated sensors, cameras and map tiles all show.
PLATFORM_WORLD_SEED = 0
M_PER_DEG_LAT = 110_540.0
M_PER_DEG_LNG_AT_EQUATOR = 111_320.0

_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_PRIME_X = np.uint64(0x9E3779B97F4A7C15)
_PRIME_Y = np.uint64(0xC2B2AE3D27D4EB4F)
_TO_UNIT = 1.0 / float(1 << 53)


def local_xy(lat: float, lng: float) -> tuple[float, float]:
    """Metres east and north of (0, 0) for a WGS84 position (equirectangular)."""
    return (
        lng * M_PER_DEG_LNG_AT_EQUATOR * math.cos(math.radians(lat)),
        lat * M_PER_DEG_LAT,
    )


def derive_key(seed: int, name: str) -> int:
    """A 64-bit key for one named field of one seeded world (stable across runs and hosts)."""
    digest = hashlib.blake2b(f"{seed}/{name}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little")


def hash_units(seed: int, *parts: object) -> list[float]:
    """Uniform numbers in [0, 1), one per 8 bytes of a hash of (seed, parts): measurement noise.

    The parts are formatted with ``repr``, so pass values already rounded to the precision at
    which two samples should count as "the same" (e.g. position to 1e-7 degrees).
    """
    count = 4
    text = repr((seed, *parts)).encode()
    digest = hashlib.blake2b(text, digest_size=8 * count).digest()
    return [
        (int.from_bytes(digest[8 * k : 8 * k + 8], "little") >> 11) * _TO_UNIT for k in range(count)
    ]


def _mix(h: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    # splitmix64 finaliser: good avalanche, cheap in numpy, wraps silently on uint64 arrays.
    h = h ^ (h >> np.uint64(30))
    h = h * _MIX1
    h = h ^ (h >> np.uint64(27))
    h = h * _MIX2
    return h ^ (h >> np.uint64(31))


Key = int | npt.NDArray[np.uint64]


def _key_array(key: Key) -> npt.NDArray[np.uint64]:
    return np.asarray(key, dtype=np.uint64)


def lattice_unit(ix: npt.NDArray[np.int64], iy: npt.NDArray[np.int64], key: Key) -> FloatArray:
    """A uniform number in [0, 1) for each integer lattice point (ix, iy) under ``key``.

    ``key`` is one 64-bit key or an array of keys broadcast against ix and iy.
    """
    h = ix.astype(np.uint64) * _PRIME_X + iy.astype(np.uint64) * _PRIME_Y + _key_array(key)
    return (_mix(h) >> np.uint64(11)).astype(np.float64) * _TO_UNIT


def _fade(t: FloatArray) -> FloatArray:
    # Quintic fade: value noise with continuous first and second derivatives (no grid creases).
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def value_noise(x: FloatArray, y: FloatArray, key: Key, scale_m: float | FloatArray) -> FloatArray:
    """Smooth noise in [-1, 1] with features about ``scale_m`` metres across.

    ``key`` and ``scale_m`` may be arrays broadcast against x and y (several layers at once).
    """
    gx = x / scale_m
    gy = y / scale_m
    fx = np.floor(gx)
    fy = np.floor(gy)
    sx = _fade(gx - fx)
    sy = _fade(gy - fy)
    ix = fx.astype(np.int64)
    iy = fy.astype(np.int64)
    one = np.int64(1)
    v00 = lattice_unit(ix, iy, key)
    v10 = lattice_unit(ix + one, iy, key)
    v01 = lattice_unit(ix, iy + one, key)
    v11 = lattice_unit(ix + one, iy + one, key)
    bottom = v00 + (v10 - v00) * sx
    top = v01 + (v11 - v01) * sx
    return (bottom + (top - bottom) * sy) * 2.0 - 1.0


def fbm(
    x: FloatArray, y: FloatArray, key: int, scale_m: float, octaves: int = 3, gain: float = 0.5
) -> FloatArray:
    """Fractal sum of ``octaves`` value-noise layers, the largest ``scale_m`` across, in [-1, 1]."""
    layers = np.arange(octaves)
    # Each octave gets its own key so layers do not line up on a shared lattice.
    keys = np.uint64(key) + np.uint64(0x632BE59BD9B4E019) * (layers + 1).astype(np.uint64)
    amplitudes = gain ** layers.astype(np.float64)
    extra = (1,) * max(x.ndim, y.ndim)
    # All octaves in one vectorised pass (stacked on a new first axis): far fewer numpy calls,
    # which is what a single-point sensor sample pays for.
    noise = value_noise(
        x[None, ...],
        y[None, ...],
        keys.reshape(-1, *extra),
        (scale_m / 2.0 ** layers.astype(np.float64)).reshape(-1, *extra),
    )
    total: FloatArray = np.tensordot(amplitudes, noise, axes=1) / amplitudes.sum()
    return total


ROAD_SPACING_NS_M = 900.0
ROAD_SPACING_EW_M = 1300.0
ROAD_HALF_WIDTH_M = 3.5


def road_warps_m(x: FloatArray, y: FloatArray, seed: int) -> tuple[FloatArray, FloatArray]:
    """The smooth sideways displacement of the two road families at (x, y), in metres.

    Split out of ``road_distance_m`` so a renderer can evaluate it on a coarse grid and
    upsample it (it is smooth), then find the sharp road edges at full resolution.
    """
    # Each family winds along its own direction only, so a road stays a single clean curve.
    warp_ns = 140.0 * fbm(np.zeros_like(x), y, derive_key(seed, "road-ns"), 1600.0, 2)
    warp_ew = 160.0 * fbm(x, np.zeros_like(y), derive_key(seed, "road-ew"), 1900.0, 2)
    return warp_ns, warp_ew


def road_distance_from_warps_m(
    x: FloatArray,
    y: FloatArray,
    warp_ns: npt.NDArray[np.floating[Any]],
    warp_ew: npt.NDArray[np.floating[Any]],
    seed: int,
) -> FloatArray:
    """Distance to the nearest road given the warps from ``road_warps_m`` at the same points."""
    u = hash_units(seed, "road-offsets")
    r_ns = np.mod(x + warp_ns + u[0] * ROAD_SPACING_NS_M, ROAD_SPACING_NS_M)
    r_ew = np.mod(y + warp_ew + u[1] * ROAD_SPACING_EW_M, ROAD_SPACING_EW_M)
    d_ns = np.minimum(r_ns, ROAD_SPACING_NS_M - r_ns)
    d_ew = np.minimum(r_ew, ROAD_SPACING_EW_M - r_ew)
    return np.minimum(d_ns, d_ew)


def road_distance_m(x: FloatArray, y: FloatArray, seed: int) -> FloatArray:
    """Approximate distance in metres to the nearest road of the seeded road network.

    Two families of gently winding roads (roughly north-south every ~900 m and east-west
    every ~1300 m); the camera draws them and NOx is higher near them.
    """
    warp_ns, warp_ew = road_warps_m(x, y, seed)
    return road_distance_from_warps_m(x, y, warp_ns, warp_ew, seed)
