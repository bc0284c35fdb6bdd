"""Map tiles of the seeded world: what the maps show under the fleet when no tile server is set.

Pure Python + numpy + Pillow (no Django). ``render_tile(z, x, y, seed=...)`` draws the standard
Web-Mercator ("slippy map") tile z/x/y as a 256 x 256 PNG of the same ground that the belly
camera photographs (``fleet.simulation.camera``): every pixel's centre is converted to WGS84,
placed in the world with ``world.local_xy`` and coloured by the camera's own ground function,
so a picture taken at a spot and the map under that spot show the same field, forest, lake or
road. There is no text on a tile.

A camera image is a flat view around its centre, a tile places every pixel exactly: they agree
at the camera's position and drift apart by about a sixth of the distance from it (the
equirectangular ``local_xy`` is slightly sheared against a flat local frame), a few metres at
the edge of a picture taken from 50 m.

Zoom levels: a pixel is 156 km at the equator at zoom 0 and 7.5 cm at zoom 21. Where a pixel
is far larger than a field, point samples of the ground are as good as any, and cheaper on a
coarse grid scaled up (``COARSE_PIXEL_M``); where roads are thinner than a pixel, they are
drawn one pixel wide so the network stays visible (``road_pixels``). The same arguments always
give the same bytes.
"""

from __future__ import annotations

import io
import math

import numpy as np
from PIL import Image

from fleet.simulation.camera import _PALETTE, _ground_colour
from fleet.simulation.world import (
    M_PER_DEG_LAT,
    M_PER_DEG_LNG_AT_EQUATOR,
    ROAD_HALF_WIDTH_M,
    FloatArray,
    road_distance_m,
)

TILE_SIZE = 256
MIN_ZOOM = 0
MAX_ZOOM = 21
# Ground size of a pixel at the equator at zoom 0 (the WGS84 equator over 256 pixels).
EQUATOR_PIXEL_M = 2.0 * math.pi * 6_378_137.0 / TILE_SIZE
# Pixels larger than this show no single field, hedge or road: the ground is sampled on a
# coarse grid (COARSE_SAMPLES per side) and scaled up, sixteen times fewer samples.
COARSE_PIXEL_M = 40.0
COARSE_SAMPLES = 64
# Roads thinner than a pixel but more than this far apart in pixels are drawn one pixel wide;
# closer than that they would only grid the tile over.
ROAD_MIN_SPACING_PX = 8.0
PALETTE_COLOURS = 256
_ROAD_SPACING_M = 900.0  # the denser road family (world.ROAD_SPACING_NS_M)
_ASPHALT = _PALETTE[11]


class TileOutOfRange(ValueError):
    """A tile address outside the Web-Mercator pyramid (zoom 0 to 21)."""


def tile_in_range(z: int, x: int, y: int) -> bool:
    """Whether z/x/y names a tile: 0 <= z <= MAX_ZOOM and 0 <= x, y < 2**z."""
    return MIN_ZOOM <= z <= MAX_ZOOM and 0 <= x < 2**z and 0 <= y < 2**z


def check_tile(z: int, x: int, y: int) -> None:
    """Raises TileOutOfRange naming what is wrong with z/x/y."""
    if not MIN_ZOOM <= z <= MAX_ZOOM:
        raise TileOutOfRange(f"zoom {z} is outside {MIN_ZOOM}..{MAX_ZOOM}")
    last = 2**z - 1
    for name, value in (("x", x), ("y", y)):
        if not 0 <= value <= last:
            raise TileOutOfRange(f"{name} = {value} is outside 0..{last} at zoom {z}")


def tile_lat_lng(z: int, x: float, y: float) -> tuple[float, float]:
    """The WGS84 latitude and longitude of tile coordinates (fractional x, y) at zoom z:
    (x, y) = (0, 0) is the north-west corner of the world, (2**z, 2**z) the south-east."""
    n = 2.0**z
    lng = x / n * 360.0 - 180.0
    lat = math.degrees(math.atan(math.sinh(math.pi * (1.0 - 2.0 * y / n))))
    return lat, lng


def pixel_size_m(z: int, lat: float) -> float:
    """Ground size of one tile pixel at zoom z and latitude lat, in metres."""
    return EQUATOR_PIXEL_M * math.cos(math.radians(lat)) / 2.0**z


def render_tile(z: int, x: int, y: int, *, seed: int) -> bytes:
    """The PNG (256 x 256, RGB) of tile z/x/y of the world ``seed`` (use the seed of the
    platform's ``SensorField`` and cameras). Raises TileOutOfRange for an address outside the
    pyramid."""
    check_tile(z, x, y)
    centre_lat, _ = tile_lat_lng(z, x + 0.5, y + 0.5)
    pixel_m = pixel_size_m(z, centre_lat)
    coarse = pixel_m > COARSE_PIXEL_M
    samples = COARSE_SAMPLES if coarse else TILE_SIZE
    sample_m = pixel_m * TILE_SIZE / samples
    wx, wy = _world_xy(z, x, y, samples)
    colour = _ground_colour(wx, wy, seed, sample_m)
    if not coarse and pixel_m > ROAD_HALF_WIDTH_M:
        on_road = road_pixels(wx, wy, seed, pixel_m)
        colour[on_road] = _ASPHALT
    pixels = np.clip(colour + 0.5, 0.0, 255.0).astype(np.uint8)
    image = Image.fromarray(pixels, "RGB")
    if coarse:
        image = image.resize((TILE_SIZE, TILE_SIZE), Image.Resampling.BILINEAR)
    # A palette of 256 colours (no dithering) keeps the ground's look in a file three to five
    # times smaller, and the tiles are kept (by the server and the browsers): worth level 6's
    # extra milliseconds too. No metadata: same pixels, same bytes.
    paletted = image.quantize(PALETTE_COLOURS, Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    buffer = io.BytesIO()
    paletted.save(buffer, format="PNG", compress_level=6)
    return buffer.getvalue()


def road_pixels(wx: FloatArray, wy: FloatArray, seed: int, pixel_m: float) -> np.ndarray:
    """Pixels a road passes through although it is narrower than they are: within half a pixel
    of a road's centre line. Empty while roads are too dense at this scale to draw apart."""
    if _ROAD_SPACING_M / pixel_m < ROAD_MIN_SPACING_PX:
        return np.zeros(wx.shape, dtype=bool)
    mask: np.ndarray = road_distance_m(wx, wy, seed) < pixel_m / 2.0
    return mask


def _world_xy(z: int, x: int, y: int, samples: int) -> tuple[FloatArray, FloatArray]:
    """World coordinates (``world.local_xy``, metres) of the centres of a samples x samples
    grid over tile z/x/y, rows from north to south."""
    n = 2.0**z
    steps = (np.arange(samples, dtype=np.float64) + 0.5) / samples
    lng = (x + steps) / n * 360.0 - 180.0
    lat = np.degrees(np.arctan(np.sinh(np.pi * (1.0 - 2.0 * (y + steps) / n))))
    lat_grid = lat[:, None]
    # local_xy, for whole arrays at once.
    wx = lng[None, :] * M_PER_DEG_LNG_AT_EQUATOR * np.cos(np.radians(lat_grid))
    wy = np.broadcast_to(lat_grid * M_PER_DEG_LAT, wx.shape)
    return wx, np.ascontiguousarray(wy)
