"""Rendered camera images of the seeded world (PNG or JPEG bytes).

Pure Python + numpy + Pillow (no Django). ``render_camera`` draws what a camera sensor would see
from a position: the "belly" view looks straight down (an aerial map of fields, forest, lakes and
roads, footprint ``max(10, 2 * alt * tan 35°)`` metres wide); the "front" and "fpv" views look
ahead along the heading, with sky, haze and the same ground in perspective, and a horizon
slightly tilted and offset by seeded attitude jitter (stronger for "fpv"). A caption (sensor
name, lat/lng/alt, the UTC date and time, see ``overlay_text``) and a crosshair are drawn on top.

The world is the one of ``fleet.simulation.world``: continuous, so nearby positions show
related pictures, and a pure function of the seed, so the same arguments always give identical
bytes (the encoders are run with fixed settings and no metadata).
"""

from __future__ import annotations

import datetime as dt
import functools
import io
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image, ImageDraw, ImageFont

from fleet.geo import Position
from fleet.simulation.sensors import CameraSettings, SensorSpec, camera_settings
from fleet.simulation.world import (
    ROAD_HALF_WIDTH_M,
    FloatArray,
    derive_key,
    fbm,
    hash_units,
    lattice_unit,
    local_xy,
    road_distance_from_warps_m,
    road_warps_m,
    value_noise,
)

IntArray = npt.NDArray[np.int64]
F32Array = npt.NDArray[np.float32]

HALF_FOV_DEG = 35.0
MIN_FOOTPRINT_M = 10.0
_TAN_HALF_FOV = math.tan(math.radians(HALF_FOV_DEG))
# Smooth fields are evaluated every _STRIDE pixels and upsampled: ~16x fewer noise evaluations.
_STRIDE = 4
_MAX_VIEW_M = 6000.0
_HAZE_M = 2200.0
_CLOUD_BASE_M = 1200.0
_FIELD_SIZE_M = (110.0, 160.0)
_HEDGE_HALF_WIDTH_M = 0.8

# Ground classes: indices into _PALETTE (the first six are crops).
_HEDGE, _FOREST, _SAND, _WATER, _VERGE, _ASPHALT = range(6, 12)
_PALETTE = np.array(
    [
        (118, 158, 62),
        (160, 178, 84),
        (204, 184, 96),
        (146, 114, 74),
        (96, 138, 60),
        (184, 192, 112),
        (58, 88, 46),
        (44, 88, 44),
        (202, 190, 150),
        (78, 128, 152),
        (156, 150, 132),
        (92, 92, 98),
    ],
    dtype=np.float32,
)
_N_CROPS = 6
# How strongly tree crowns modulate brightness, and how much depth darkens, per class.
_CROWN_AMP = np.zeros(len(_PALETTE), dtype=np.float32)
_CROWN_AMP[_FOREST] = 0.35
_DEPTH_AMP = np.zeros(len(_PALETTE), dtype=np.float32)
_DEPTH_AMP[_WATER] = 0.45
_HAZE = np.array((196, 208, 224), dtype=np.float32)
_ZENITH = np.array((64, 112, 196), dtype=np.float32)
_CLOUD = np.array((244, 246, 250), dtype=np.float32)


def render_camera(
    sensor: SensorSpec,
    position: Position,
    time_s: float,
    *,
    seed: int,
    heading_deg: float = 0.0,
    epoch_s: float | None = None,
) -> bytes:
    """The encoded image that camera ``sensor`` takes at ``position`` and ``time_s``.

    ``seed`` picks the world (use the same seed as the ``SensorField``); ``heading_deg`` is the
    direction the vehicle faces, clockwise from north (the top of a belly image points there).
    ``epoch_s`` is the moment the caption prints, Unix epoch seconds (the reading's ``time``);
    by default ``time_s``, which is on the Unix epoch in a live system but counts from 0 in a
    simulation. Returns PNG bytes, or JPEG bytes when ``params["format"]`` is "jpeg", of exactly
    ``params["width"]`` x ``params["height"]`` pixels (default 640x480). Raises ValueError if the
    sensor is not a valid camera (see ``camera_settings``) or a time or the heading is not finite.
    """
    settings = camera_settings(sensor)
    if not math.isfinite(time_s):
        raise ValueError(f"time_s must be a finite number, got {time_s!r}")
    if epoch_s is not None and not math.isfinite(epoch_s):
        raise ValueError(f"epoch_s must be a finite number, got {epoch_s!r}")
    if not math.isfinite(heading_deg):
        raise ValueError(f"heading_deg must be a finite number, got {heading_deg!r}")
    heading = math.radians(heading_deg % 360.0)
    if settings.view == "belly":
        pixels = _render_belly(settings, position, seed, heading)
    else:
        pixels = _render_perspective(settings, position, seed, heading, sensor.name, time_s)
    image = Image.fromarray(np.clip(pixels + 0.5, 0.0, 255.0).astype(np.uint8), "RGB")
    caption = overlay_text(sensor.name, position, time_s if epoch_s is None else epoch_s)
    _draw_overlay(image, caption)
    return _encode(image, settings.format)


@dataclass(frozen=True)
class _Grid:
    """Coarse sample nodes of an image and the weights that upsample them bilinearly."""

    rows: IntArray
    cols: IntArray
    row_k: IntArray
    row_f: F32Array
    col_k: IntArray
    col_f: F32Array

    def coarse(self, full: npt.NDArray[Any]) -> npt.NDArray[Any]:
        return full[np.ix_(self.rows, self.cols)]

    def upsample(self, coarse: npt.NDArray[Any]) -> F32Array:
        """Bilinear upsampling of a (rows, cols, ...) node array to full size, in float32."""
        values = coarse.astype(np.float32)
        extra = (1,) * (values.ndim - 2)
        rf = self.row_f.reshape(-1, 1, *extra)
        cf = self.col_f.reshape(1, -1, *extra)
        tall = values[self.row_k] * (1.0 - rf) + values[self.row_k + 1] * rf
        full: F32Array = tall[:, self.col_k] * (1.0 - cf) + tall[:, self.col_k + 1] * cf
        return full


def _nodes(n: int) -> tuple[IntArray, IntArray, F32Array]:
    nodes = np.unique(np.r_[np.arange(0, n, _STRIDE), n - 1]).astype(np.int64)
    if len(nodes) == 1:
        # A one-pixel-wide image: duplicate the node so there is always a pair to blend.
        nodes = np.array([0, 0], dtype=np.int64)
    index = np.arange(n, dtype=np.int64)
    k = np.minimum(index // _STRIDE, len(nodes) - 2)
    span = np.maximum(nodes[k + 1] - nodes[k], 1)
    frac = np.clip((index - nodes[k]) / span, 0.0, 1.0).astype(np.float32)
    return nodes, k, frac


def _grid(height: int, width: int) -> _Grid:
    rows, row_k, row_f = _nodes(height)
    cols, col_k, col_f = _nodes(width)
    return _Grid(rows, cols, row_k, row_f, col_k, col_f)


def _ground_colour(x: FloatArray, y: FloatArray, seed: int, pixel_m: F32Array | float) -> F32Array:
    """RGB (float32, 0..255) of the ground at world points (x, y), seen at pixel_m resolution.

    Smooth fields come from a coarse grid; class boundaries (fields, hedges, roads, shores) are
    decided per pixel so they stay sharp.
    """
    grid = _grid(*x.shape)
    xc = grid.coarse(x)
    yc = grid.coarse(y)
    warp_ns, warp_ew = road_warps_m(xc, yc, seed)
    smooth = grid.upsample(
        np.stack(
            [
                fbm(xc, yc, derive_key(seed, "land-water"), 700.0, 3),
                fbm(xc, yc, derive_key(seed, "land-forest"), 320.0, 3),
                fbm(xc, yc, derive_key(seed, "land-texture"), 14.0, 2),
                value_noise(xc, yc, derive_key(seed, "land-crowns"), 3.0),
                warp_ns,
                warp_ew,
            ],
            axis=-1,
        )
    )
    water, forest, texture, crowns = (smooth[..., k] for k in range(4))
    road = road_distance_from_warps_m(x, y, smooth[..., 4], smooth[..., 5], seed)

    # Fields: a patchwork of rectangles in a seeded orientation, rows shifted so the
    # boundaries do not line up into a perfect grid.
    angle = hash_units(seed, "field-angle")[0] * math.pi
    u = x * math.cos(angle) + y * math.sin(angle)
    v = y * math.cos(angle) - x * math.sin(angle)
    size_u, size_v = _FIELD_SIZE_M
    gv = v / size_v
    iv = np.floor(gv).astype(np.int64)
    shift = lattice_unit(iv, np.zeros_like(iv), derive_key(seed, "field-shift")) * size_u
    gu = (u + shift) / size_u
    iu = np.floor(gu).astype(np.int64)
    label = (lattice_unit(iu, iv, derive_key(seed, "field-crop")) * _N_CROPS).astype(np.intp)
    fu = gu - iu
    fv = gv - iv
    edge_m = np.minimum(
        np.minimum(fu, 1.0 - fu) * size_u, np.minimum(fv, 1.0 - fv) * size_v
    ).astype(np.float32)
    # Hedges thinner than a pixel would only alias into noise, so they fade out from afar.
    hedge = (edge_m < _HEDGE_HALF_WIDTH_M) & (pixel_m < 2.0 * _HEDGE_HALF_WIDTH_M)
    label[hedge] = _HEDGE
    label[forest > 0.18] = _FOREST
    label[road < ROAD_HALF_WIDTH_M + 1.5] = _VERGE
    label[road < ROAD_HALF_WIDTH_M] = _ASPHALT
    label[water < -0.262] = _SAND
    label[water < -0.27] = _WATER

    depth = np.clip((-0.27 - water) * 4.0, 0.0, 1.0)
    shade = 1.0 + 0.1 * texture + _CROWN_AMP[label] * (crowns - 0.3) - _DEPTH_AMP[label] * depth
    colour: F32Array = _PALETTE[label] * shade[..., None]
    return colour


def _render_belly(
    settings: CameraSettings, position: Position, seed: int, heading: float
) -> F32Array:
    width, height = settings.width, settings.height
    footprint_m = max(MIN_FOOTPRINT_M, 2.0 * max(position.alt, 0.0) * _TAN_HALF_FOV)
    pixel_m = footprint_m / width
    right = (np.arange(width, dtype=np.float64) + 0.5 - width / 2.0) * pixel_m
    ahead = (height / 2.0 - np.arange(height, dtype=np.float64) - 0.5) * pixel_m
    x0, y0 = local_xy(position.lat, position.lng)
    sin_h, cos_h = math.sin(heading), math.cos(heading)
    x = x0 + ahead[:, None] * sin_h + right[None, :] * cos_h
    y = y0 + ahead[:, None] * cos_h - right[None, :] * sin_h
    return _ground_colour(x, y, seed, pixel_m)


def _render_perspective(
    settings: CameraSettings,
    position: Position,
    seed: int,
    heading: float,
    sensor_name: str,
    time_s: float,
) -> F32Array:
    width, height = settings.width, settings.height
    jitter = hash_units(seed, sensor_name, "attitude", round(time_s, 1))
    if settings.view == "fpv":
        pitch_deg, roll_deg = 12.0 + 8.0 * (jitter[0] - 0.5), 16.0 * (jitter[1] - 0.5)
    else:
        pitch_deg, roll_deg = 6.0 + 3.0 * (jitter[0] - 0.5), 4.0 * (jitter[1] - 0.5)
    pitch, roll = math.radians(pitch_deg), math.radians(roll_deg)

    # Ray directions in float32 (plenty for directions); world positions stay float64 below.
    focal = np.float32((width / 2.0) / _TAN_HALF_FOV)
    px = (np.arange(width, dtype=np.float32) + np.float32(0.5 - width / 2.0))[None, :]
    py = (np.float32(height / 2.0 - 0.5) - np.arange(height, dtype=np.float32))[:, None]
    cos_r, sin_r = np.float32(math.cos(roll)), np.float32(math.sin(roll))
    cos_p, sin_p = np.float32(math.cos(pitch)), np.float32(math.sin(pitch))
    # Camera ray -> world: roll about the optical axis, pitch down, then turn to the heading.
    side = px * cos_r - py * sin_r
    lift = px * sin_r + py * cos_r
    up = lift * cos_p - focal * sin_p
    forward = lift * sin_p + focal * cos_p
    level = np.hypot(forward, side)
    sin_h, cos_h = math.sin(heading), math.cos(heading)
    dir_east = (forward * np.float32(sin_h) + side * np.float32(cos_h)) / level
    dir_north = (forward * np.float32(cos_h) - side * np.float32(sin_h)) / level

    ground = up < 0.0
    ground_rows = np.flatnonzero(ground.any(axis=1))
    sky_rows = np.flatnonzero((~ground).any(axis=1))
    pixels = np.empty((height, width, 3), dtype=np.float32)
    x0, y0 = local_xy(position.lat, position.lng)

    if ground_rows.size:
        band = slice(int(ground_rows[0]), height)
        b_up, b_level = up[band], level[band]
        eye_m = np.float32(max(position.alt, 1.5))
        # Sky pixels in the band get the farthest ground point: no jump for the coarse grid.
        reach = np.minimum(eye_m * b_level / np.maximum(-b_up, np.float32(1e-6)), _MAX_VIEW_M)
        reach = np.where(ground[band], reach, np.float32(_MAX_VIEW_M))
        x = x0 + (dir_east[band] * reach).astype(np.float64)
        y = y0 + (dir_north[band] * reach).astype(np.float64)
        # Ground size of a pixel: slant range / focal length, stretched by the grazing angle.
        slant2 = b_level * b_level + b_up * b_up
        pixel_m = reach * slant2 / (b_level * focal * np.maximum(-b_up, 0.05 * np.sqrt(slant2)))
        land = _ground_colour(x, y, seed, pixel_m)
        haze = (1.0 - np.exp(reach * np.float32(-1.0 / _HAZE_M)))[..., None]
        pixels[band] = land + (_HAZE - land) * haze

    if sky_rows.size:
        band = slice(0, int(sky_rows[-1]) + 1)
        grid = _grid(band.stop, width)
        c_up = grid.coarse(up[band]).astype(np.float64)
        c_level = grid.coarse(level[band]).astype(np.float64)
        elevation = np.arctan2(c_up, c_level)
        sky_t = (np.clip(elevation / 0.7, 0.0, 1.0) ** 0.7)[..., None]
        sky = _HAZE * (1.0 - sky_t) + _ZENITH * sky_t
        cloud_reach = np.minimum(_CLOUD_BASE_M * c_level / np.maximum(c_up, 1e-3), 40_000.0)
        cloud = fbm(
            x0 + grid.coarse(dir_east[band]) * cloud_reach,
            y0 + grid.coarse(dir_north[band]) * cloud_reach,
            derive_key(seed, "clouds"),
            900.0,
            3,
        )
        # Clouds fade toward the horizon like the ground does, so the horizon stays hazy.
        cover = (np.clip((cloud - 0.1) * 3.0, 0.0, 1.0) * np.clip(elevation / 0.15, 0.0, 1.0))[
            ..., None
        ]
        sky_full = grid.upsample(sky + (_CLOUD - sky) * cover)
        if ground_rows.size and ground_rows[0] < band.stop:
            mixed = slice(int(ground_rows[0]), band.stop)
            pixels[mixed] = np.where(ground[mixed][..., None], pixels[mixed], sky_full[mixed])
            pixels[: mixed.start] = sky_full[: mixed.start]
        else:
            pixels[band] = sky_full
    return pixels


@functools.lru_cache(maxsize=8)
def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


def overlay_text(sensor_name: str, position: Position, epoch_s: float) -> str:
    """The caption a picture carries: the sensor, where (degrees to 6 decimals, about 0.1 m;
    altitude to 0.1 m) and when, as a UTC date and time to the second (``2026-11-27 13:04:05
    UTC``, the time of the reading rounded down, as a clock shows it). A moment no calendar date
    can hold (beyond the year 9999) is printed as epoch seconds instead."""
    try:
        moment = dt.datetime.fromtimestamp(math.floor(epoch_s), tz=dt.UTC)
        when = moment.strftime("%Y-%m-%d %H:%M:%S UTC")
    except (OverflowError, OSError, ValueError):
        when = f"t = {epoch_s:.2f} s"
    return (
        f"{sensor_name}\n{position.lat:.6f}, {position.lng:.6f}  alt {position.alt:.1f} m\n{when}"
    )


def _draw_overlay(image: Image.Image, text: str) -> None:
    """Caption box with ``text`` in the top-left corner and a crosshair in the centre."""
    width, height = image.size
    draw = ImageDraw.Draw(image)
    font = _font(max(10, min(width, height) // 40))
    left, top, right, bottom = draw.multiline_textbbox((8, 6), text, font=font, spacing=2)
    box = (
        max(0, math.floor(left) - 4),
        max(0, math.floor(top) - 3),
        min(width, math.ceil(right) + 4),
        min(height, math.ceil(bottom) + 3),
    )
    if box[2] > box[0] and box[3] > box[1]:
        region = image.crop(box).point(lambda v: v * 2 // 5)
        image.paste(region, box)
    draw.multiline_text((8, 6), text, fill=(255, 255, 255), font=font, spacing=2)

    cx, cy = width // 2, height // 2
    arm = max(4, min(width, height) // 24)
    gap = max(2, arm // 3)
    for colour, line_width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        draw.line((cx - arm, cy, cx - gap, cy), fill=colour, width=line_width)
        draw.line((cx + gap, cy, cx + arm, cy), fill=colour, width=line_width)
        draw.line((cx, cy - arm, cx, cy - gap), fill=colour, width=line_width)
        draw.line((cx, cy + gap, cx, cy + arm), fill=colour, width=line_width)


def _encode(image: Image.Image, fmt: str) -> bytes:
    buffer = io.BytesIO()
    # Fixed encoder settings and no metadata (Pillow writes no timestamp chunk): same pixels,
    # same bytes. PNG level 1: level 6 costs ~3x the time for ~25 % smaller files.
    if fmt == "jpeg":
        image.save(buffer, format="JPEG", quality=88, optimize=False, progressive=False)
    else:
        image.save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()
