"""Map tiles of the seeded world: standard Web-Mercator tiles of the ground the cameras see."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from PIL import Image

from fleet.geo import Position
from fleet.simulation import SensorSpec, render_camera
from fleet.simulation.tiles import (
    MAX_ZOOM,
    TileOutOfRange,
    check_tile,
    pixel_size_m,
    render_tile,
    tile_lat_lng,
)

BELLY = SensorSpec(
    "Belly Mounted Camera 640x480", "camera", params={"width": 640, "height": 480, "view": "belly"}
)
# Spots over the paper's field (examples/scenarios): forest, crops of several kinds, a road.
SPOTS = [(48.109 + 0.0003 * k, 12.859 + 0.00055 * k) for k in range(16)]


def _pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)


def _tile_of(lat: float, lng: float, z: int) -> tuple[int, int, int, int]:
    """The tile x, y at zoom z holding (lat, lng), and the pixel column and row in it."""
    n = 2**z
    fx = (lng + 180.0) / 360.0 * n
    fy = (1.0 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2.0 * n
    return int(fx), int(fy), int(fx % 1 * 256), int(fy % 1 * 256)


@pytest.mark.parametrize("z", [0, 5, 11, 13, 17, 21])
def test_a_tile_is_a_256_pixel_png_at_every_zoom(z: int) -> None:
    x, y, _, _ = _tile_of(48.1111, 12.8619, z)
    image = Image.open(io.BytesIO(render_tile(z, x, y, seed=0)))
    assert image.format == "PNG"
    assert image.size == (256, 256)
    assert image.convert("RGB").getextrema() != ((0, 0), (0, 0), (0, 0))


def test_the_same_tile_is_the_same_bytes_and_another_seed_another_world() -> None:
    x, y, _, _ = _tile_of(48.1111, 12.8619, 16)
    first = render_tile(16, x, y, seed=0)
    assert render_tile(16, x, y, seed=0) == first
    assert np.abs(_pixels(render_tile(16, x, y, seed=1)) - _pixels(first)).mean() > 20.0
    assert np.abs(_pixels(render_tile(16, x + 1, y, seed=0)) - _pixels(first)).mean() > 20.0


def test_the_map_shows_what_the_belly_camera_photographs_at_each_spot() -> None:
    """The colour under a spot on the map is the colour at the centre of a picture taken
    straight down from above it (the crosshair leaves a few pixels free there)."""
    for lat, lng in SPOTS:
        photo = _pixels(render_camera(BELLY, Position(lat, lng, 20.0), 0.0, seed=0))
        centre = photo[236:245, 316:325].reshape(-1, 3).mean(axis=0)
        x, y, col, row = _tile_of(lat, lng, MAX_ZOOM)
        tile = _pixels(render_tile(MAX_ZOOM, x, y, seed=0))
        under = tile[max(row - 1, 0) : row + 2, max(col - 1, 0) : col + 2].reshape(-1, 3)
        assert np.abs(under.mean(axis=0) - centre).max() < 10.0, (lat, lng, centre, under)


def test_a_tile_lines_up_with_its_neighbours() -> None:
    """The last column of a tile and the first of the next are neighbouring strips of ground:
    as alike as two neighbouring columns inside a tile."""
    x, y, _, _ = _tile_of(48.1111, 12.8619, 18)
    left, right = _pixels(render_tile(18, x, y, seed=0)), _pixels(render_tile(18, x + 1, y, seed=0))
    across = np.abs(left[:, -1] - right[:, 0]).mean()
    inside = np.abs(left[:, -2] - left[:, -1]).mean()
    assert across < inside + 6.0


def test_roads_stay_visible_when_they_are_narrower_than_a_pixel() -> None:
    """At zoom 13 a pixel is about 13 m, a road 7 m: still drawn, as unbroken lines of asphalt
    (point samples alone would hit a road in about every other pixel along it)."""
    asphalt = np.array([92.0, 92.0, 98.0])
    x, y, _, _ = _tile_of(48.1111, 12.8619, 13)
    tile = _pixels(render_tile(13, x, y, seed=0))
    on_road = np.abs(tile - asphalt).max(axis=-1) < 4.0
    # The north-south roads (every ~900 m, ~3.6 across the tile) cross every row.
    assert on_road.any(axis=1).all()
    assert on_road.mean() > 0.018  # about six lines a pixel wide


def test_tile_geometry_is_web_mercator() -> None:
    assert tile_lat_lng(0, 0, 0) == pytest.approx((85.0511287798, -180.0))
    assert tile_lat_lng(0, 0.5, 0.5) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert tile_lat_lng(1, 2, 2) == pytest.approx((-85.0511287798, 180.0))
    assert pixel_size_m(0, 0.0) == pytest.approx(156_543.03, rel=1e-6)
    assert pixel_size_m(21, 48.0) == pytest.approx(0.05, rel=0.02)


@pytest.mark.parametrize(
    ("z", "x", "y", "message"),
    [
        (22, 0, 0, "zoom 22 is outside 0..21"),
        (-1, 0, 0, "zoom -1 is outside 0..21"),
        (0, 1, 0, "x = 1 is outside 0..0 at zoom 0"),
        (3, 0, 8, "y = 8 is outside 0..7 at zoom 3"),
        (3, -1, 0, "x = -1 is outside 0..7 at zoom 3"),
    ],
)
def test_an_address_outside_the_pyramid_is_refused_saying_why(
    z: int, x: int, y: int, message: str
) -> None:
    with pytest.raises(TileOutOfRange, match=f"^{message}$"):
        check_tile(z, x, y)
    with pytest.raises(TileOutOfRange):
        render_tile(z, x, y, seed=0)
