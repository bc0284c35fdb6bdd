"""What a VV's program may do with a picture it received (``VV.image.*``): measure a region's
colours, count the pixels in a colour range, cut a region out, scale the picture.

Pure: bytes in, numbers or PNG bytes out, no Django (the services package finds the picture,
checks the VV may use it and stores a new one). Every function reads the picture as RGB
(``Image.convert("RGB")``), computes in NumPy float64 and rounds to 6 decimals, so the same
picture gives the same answer on every host. A wrong argument raises ``ImagingError`` whose
message names the argument and says why, ready to follow the call as the program wrote it.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image, UnidentifiedImageError

# A picture is decoded whole, so its size bounds the memory a call takes: a small file that
# claims a huge picture (a decompression bomb) is refused before its pixels are read.
MAX_PIXELS = 40_000_000
MAX_SIDE = 4096  # resize's width and height
FORMATS = ("PNG", "JPEG")  # what the platform's cameras give; no other decoder is reached
CHANNELS = ("r", "g", "b")
DECIMALS = 6


class ImagingError(ValueError):
    """An argument the call cannot use; the message names it and says why."""


@dataclass(frozen=True)
class Region:
    """A rectangle of a picture in pixels: its top-left corner and its size."""

    x: int
    y: int
    width: int
    height: int

    def __post_init__(self) -> None:
        for name, least in (("x", 0), ("y", 0), ("width", 1), ("height", 1)):
            value = _integer(getattr(self, name), f"region.{name}")
            if value < least:
                raise ImagingError(f"region.{name} = {value} must be at least {least}")

    @classmethod
    def from_json(cls, value: object) -> Region:
        """The region a program gave (``{x, y, width, height}``). ImagingError otherwise."""
        if not isinstance(value, Mapping):
            raise ImagingError("region must be an object {x, y, width, height}")
        missing = [name for name in ("x", "y", "width", "height") if name not in value]
        if missing:
            raise ImagingError(f"region has no {', '.join(missing)}")
        return cls(value["x"], value["y"], value["width"], value["height"])


@dataclass(frozen=True)
class Picture:
    """A picture made by ``crop`` or ``resize``: PNG bytes and the size in pixels."""

    data: bytes
    width: int
    height: int


def stats(data: bytes, region: Region | None = None) -> dict[str, Any]:
    """Size, mean and population standard deviation of each RGB channel over the region (the
    whole picture without one): ``{width, height, mean: {r, g, b}, std: {r, g, b}}``.

    ``width`` and ``height`` are the measured area's. ImagingError for a picture that cannot be
    read or a region outside it.
    """
    area = _area(_open(data).convert("RGB"), region)
    pixels = area.width * area.height
    values = np.arange(256, dtype=np.float64)
    # The channel histograms give the exact sums the pixel arrays would, in 256 terms instead
    # of one per pixel: a 40-megapixel picture needs no float copy of its pixels.
    counts = np.asarray(area.histogram(), dtype=np.float64).reshape(3, 256)
    mean = counts @ values / pixels
    variance = ((values[None, :] - mean[:, None]) ** 2 * counts).sum(axis=1) / pixels
    std = np.sqrt(variance)
    return {
        "width": area.width,
        "height": area.height,
        "mean": {c: round(float(m), DECIMALS) for c, m in zip(CHANNELS, mean, strict=True)},
        "std": {c: round(float(s), DECIMALS) for c, s in zip(CHANNELS, std, strict=True)},
    }


def fraction(data: bytes, ranges: Mapping[str, Any], region: Region | None = None) -> float:
    """The share of the region's pixels whose every channel named in ``ranges`` (``{r: [min,
    max], g: ..., b: ...}``, bounds included) is in its range, rounded to 6 decimals.

    ImagingError for bad ranges, a picture that cannot be read or a region outside it.
    """
    bounds = _ranges(ranges)
    area = _area(_open(data).convert("RGB"), region)
    pixels = np.asarray(area)
    inside = np.ones(pixels.shape[:2], dtype=bool)
    for channel, (low, high) in bounds.items():
        values = pixels[:, :, CHANNELS.index(channel)]
        inside &= (values >= low) & (values <= high)
    return round(int(np.count_nonzero(inside)) / (area.width * area.height), DECIMALS)


def crop(data: bytes, region: Region) -> Picture:
    """The region of the picture as a new PNG picture of the region's size.

    ImagingError for a picture that cannot be read or a region outside it.
    """
    image = _open(data)
    return _png(_area(image.convert(_mode(image)), region))


def resize(data: bytes, width: int, height: int) -> Picture:
    """The picture scaled to ``width`` x ``height`` pixels (1..4096 each; bilinear), as PNG.

    ImagingError for a bad size or a picture that cannot be read.
    """
    size = []
    for name, value in (("width", width), ("height", height)):
        number = _integer(value, name)
        if not 1 <= number <= MAX_SIDE:
            raise ImagingError(f"{name} = {number} must be between 1 and {MAX_SIDE}")
        size.append(number)
    image = _open(data)
    scaled = image.convert(_mode(image)).resize((size[0], size[1]), Image.Resampling.BILINEAR)
    return _png(scaled)


def _open(data: bytes) -> Image.Image:
    """The decoded picture. ImagingError for bytes that are not a PNG or JPEG picture, or one
    of more than MAX_PIXELS pixels (checked from its header, before decoding)."""
    try:
        image = Image.open(io.BytesIO(data), formats=FORMATS)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise ImagingError(
            f"picture: larger than the {MAX_PIXELS:,} pixels an image call reads"
        ) from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        raise ImagingError("picture: not a readable PNG or JPEG image") from None
    width, height = image.size
    if width * height > MAX_PIXELS:
        raise ImagingError(
            f"picture: {width} x {height} = {width * height:,} pixels is more than the "
            f"{MAX_PIXELS:,} an image call reads"
        )
    try:
        image.load()
    except (OSError, ValueError, SyntaxError):
        raise ImagingError("picture: not a readable PNG or JPEG image") from None
    return image


def _mode(image: Image.Image) -> str:
    """What crop and resize keep: RGB, or RGBA for a picture with transparency."""
    return "RGBA" if image.has_transparency_data else "RGB"


def _area(image: Image.Image, region: Region | None) -> Image.Image:
    if region is None:
        return image
    for corner, size, side in (("x", "width", image.width), ("y", "height", image.height)):
        end = getattr(region, corner) + getattr(region, size)
        if end > side:
            raise ImagingError(
                f"region.{corner} + region.{size} = {end} is beyond the picture's {size} {side}"
            )
    box = (region.x, region.y, region.x + region.width, region.y + region.height)
    return image.crop(box)


def _png(image: Image.Image) -> Picture:
    out = io.BytesIO()
    image.save(out, format="PNG", optimize=False)
    return Picture(out.getvalue(), image.width, image.height)


def _ranges(ranges: object) -> dict[str, tuple[int, int]]:
    """The checked ``{channel: (min, max)}`` of a program's ranges."""
    if not isinstance(ranges, Mapping):
        raise ImagingError("ranges must be an object {r, g, b} of [min, max] pairs")
    if not ranges:
        raise ImagingError("ranges has no channel: give at least one of r, g, b")
    bounds = {}
    for channel, pair in ranges.items():
        if channel not in CHANNELS:
            raise ImagingError(f"ranges.{channel} is not a channel: the channels are r, g and b")
        if not isinstance(pair, list | tuple) or len(pair) != 2:
            raise ImagingError(f"ranges.{channel} must be a pair [min, max]")
        low, high = (_integer(v, f"ranges.{channel}[{i}]") for i, v in enumerate(pair))
        for i, value in enumerate((low, high)):
            if not 0 <= value <= 255:
                raise ImagingError(f"ranges.{channel}[{i}] = {value} must be between 0 and 255")
        if low > high:
            raise ImagingError(f"ranges.{channel}: min {low} is more than max {high}")
        bounds[channel] = (low, high)
    return bounds


def _integer(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ImagingError(f"{name} must be an integer")
    return value
