"""The image functions a VV's program calls (VV.image.*), on pictures of known content."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from vvm_worker.imaging import ImagingError, Region, crop, fraction, resize, stats

GREEN = (20, 200, 40)
RED = (210, 30, 0)


def png(image: Image.Image) -> bytes:
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()


def solid(colour: tuple[int, ...], size: tuple[int, int] = (40, 30), mode: str = "RGB") -> bytes:
    return png(Image.new(mode, size, colour))


def halves(width: int = 64, height: int = 32) -> bytes:
    """Green on the left half, red on the right."""
    image = Image.new("RGB", (width, height), RED)
    image.paste(GREEN, (0, 0, width // 2, height))
    return png(image)


def gradient_pixels(width: int = 97, height: int = 61) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width]
    return np.stack([(x * 255) // (width - 1), (y * 7) % 256, (x * y) % 251], axis=-1).astype(
        np.uint8
    )


def pixels(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def png_header(width: int, height: int) -> bytes:
    """A PNG that claims a size without holding its pixels (what a decompression bomb does)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b""))
        + chunk(b"IEND", b"")
    )


# stats


def test_stats_of_a_solid_picture_are_its_colour_without_spread() -> None:
    assert stats(solid(GREEN)) == {
        "width": 40,
        "height": 30,
        "mean": {"r": 20.0, "g": 200.0, "b": 40.0},
        "std": {"r": 0.0, "g": 0.0, "b": 0.0},
    }


def test_stats_of_two_halves_give_the_population_standard_deviation() -> None:
    result = stats(halves())
    assert result["mean"] == {"r": 115.0, "g": 115.0, "b": 20.0}
    # Half the pixels at each of two values: the population std is half their distance.
    assert result["std"] == {"r": 95.0, "g": 85.0, "b": 20.0}


def test_stats_of_a_gradient_match_numpy_over_the_pixels_rounded_to_6_decimals() -> None:
    array = gradient_pixels()
    result = stats(png(Image.fromarray(array, "RGB")))
    values = array.reshape(-1, 3).astype(np.float64)
    assert result["mean"] == {
        c: round(float(v), 6) for c, v in zip("rgb", values.mean(axis=0), strict=True)
    }
    assert result["std"] == {
        c: round(float(v), 6) for c, v in zip("rgb", values.std(axis=0), strict=True)
    }
    assert result["mean"]["r"] != round(result["mean"]["r"])  # a case where rounding matters


def test_stats_of_a_region_measure_only_the_region() -> None:
    left = stats(halves(), Region(x=2, y=3, width=30, height=20))
    assert left == {
        "width": 30,
        "height": 20,
        "mean": {"r": 20.0, "g": 200.0, "b": 40.0},
        "std": {"r": 0.0, "g": 0.0, "b": 0.0},
    }
    array = gradient_pixels()
    part = stats(png(Image.fromarray(array, "RGB")), Region(10, 5, 40, 30))
    values = array[5:35, 10:50].reshape(-1, 3).astype(np.float64)
    assert part["std"]["b"] == round(float(values[:, 2].std()), 6)


def test_stats_read_a_jpeg_and_a_grey_or_transparent_picture_as_rgb() -> None:
    out = io.BytesIO()
    Image.new("RGB", (50, 20), (128, 128, 128)).save(out, format="JPEG", quality=95)
    result = stats(out.getvalue())
    assert (result["width"], result["height"]) == (50, 20)
    assert abs(result["mean"]["g"] - 128) < 2
    assert stats(solid(90, mode="L"))["mean"] == {"r": 90.0, "g": 90.0, "b": 90.0}
    assert stats(solid((1, 2, 3, 0), mode="RGBA"))["mean"] == {"r": 1.0, "g": 2.0, "b": 3.0}


# fraction


def test_fraction_of_a_half_green_picture_in_a_green_range_is_one_half() -> None:
    assert fraction(halves(), {"g": [150, 255], "r": [0, 100]}) == 0.5


def test_fraction_bounds_are_inclusive_and_every_given_channel_must_be_in_range() -> None:
    assert fraction(halves(), {"g": [200, 200]}) == 0.5
    assert fraction(halves(), {"g": [201, 255]}) == 0.0
    assert fraction(halves(), {"r": [0, 255], "g": [0, 255], "b": [0, 255]}) == 1.0
    # Green's r is in range, red's g is too: no pixel has both.
    assert fraction(halves(), {"r": [0, 50], "g": [0, 50]}) == 0.0


def test_fraction_counts_only_the_region_and_rounds_to_6_decimals() -> None:
    assert fraction(halves(), {"g": [150, 255]}, Region(0, 0, 32, 32)) == 1.0
    assert fraction(halves(), {"g": [150, 255]}, Region(32, 0, 32, 32)) == 0.0
    assert fraction(halves(), {"g": [150, 255]}, Region(16, 0, 32, 1)) == 0.5
    image = Image.new("RGB", (3, 1), RED)
    image.putpixel((1, 0), GREEN)
    assert fraction(png(image), {"g": [100, 255]}) == 0.333333


# crop


def test_crop_gives_a_png_of_the_region_with_its_pixels() -> None:
    array = gradient_pixels()
    result = crop(png(Image.fromarray(array, "RGB")), Region(x=10, y=5, width=40, height=30))
    assert (result.width, result.height) == (40, 30)
    assert Image.open(io.BytesIO(result.data)).format == "PNG"
    assert np.array_equal(pixels(result.data), array[5:35, 10:50])


def test_crop_of_the_whole_picture_keeps_it_and_is_deterministic() -> None:
    array = gradient_pixels()
    data = png(Image.fromarray(array, "RGB"))
    whole = crop(data, Region(0, 0, 97, 61))
    assert np.array_equal(pixels(whole.data), array)
    assert crop(data, Region(0, 0, 97, 61)).data == whole.data


def test_crop_keeps_transparency() -> None:
    result = crop(solid((10, 20, 30, 77), mode="RGBA"), Region(1, 1, 5, 5))
    image = Image.open(io.BytesIO(result.data))
    assert image.mode == "RGBA" and image.getpixel((0, 0)) == (10, 20, 30, 77)


# resize


def test_resize_gives_a_png_of_the_requested_size() -> None:
    result = resize(halves(), 16, 100)
    assert (result.width, result.height) == (16, 100)
    image = Image.open(io.BytesIO(result.data))
    assert image.format == "PNG" and image.size == (16, 100)
    assert image.convert("RGB").getpixel((0, 50)) == GREEN
    assert image.convert("RGB").getpixel((15, 50)) == RED


def test_resize_is_pillows_bilinear_and_deterministic() -> None:
    array = gradient_pixels()
    data = png(Image.fromarray(array, "RGB"))
    expected = Image.fromarray(array, "RGB").resize((33, 20), Image.Resampling.BILINEAR)
    result = resize(data, 33, 20)
    assert np.array_equal(pixels(result.data), np.asarray(expected))
    assert resize(data, 33, 20).data == result.data
    assert (resize(data, 4096, 1).width, resize(data, 1, 4096).height) == (4096, 4096)


# wrong arguments: each message names the argument and says why


@pytest.mark.parametrize(
    ("region", "message"),
    [
        (Region(0, 0, 65, 10), "region.x + region.width = 65 is beyond the picture's width 64"),
        (Region(60, 0, 5, 10), "region.x + region.width = 65 is beyond the picture's width 64"),
        (Region(0, 30, 4, 3), "region.y + region.height = 33 is beyond the picture's height 32"),
        (Region(64, 0, 1, 1), "region.x + region.width = 65 is beyond the picture's width 64"),
    ],
)
def test_a_region_outside_the_picture_is_refused(region: Region, message: str) -> None:
    for call in (
        lambda: stats(halves(), region),
        lambda: fraction(halves(), {"r": [0, 255]}, region),
        lambda: crop(halves(), region),
    ):
        with pytest.raises(ImagingError) as error:
            call()
        assert str(error.value) == message


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ({"x": -1, "y": 0, "width": 1, "height": 1}, "region.x = -1 must be at least 0"),
        ({"x": 0, "y": -3, "width": 1, "height": 1}, "region.y = -3 must be at least 0"),
        ({"x": 0, "y": 0, "width": 0, "height": 1}, "region.width = 0 must be at least 1"),
        ({"x": 0, "y": 0, "width": 1, "height": -2}, "region.height = -2 must be at least 1"),
        ({"x": 1.5, "y": 0, "width": 1, "height": 1}, "region.x must be an integer"),
        ({"x": 0, "y": True, "width": 1, "height": 1}, "region.y must be an integer"),
        ({"x": 0, "y": 0, "width": "2", "height": 1}, "region.width must be an integer"),
        ({"x": 0, "y": 0}, "region has no width, height"),
        ([0, 0, 1, 1], "region must be an object {x, y, width, height}"),
        (None, "region must be an object {x, y, width, height}"),
    ],
)
def test_a_malformed_region_is_refused(value: object, message: str) -> None:
    with pytest.raises(ImagingError) as error:
        Region.from_json(value)
    assert str(error.value) == message


@pytest.mark.parametrize(
    ("ranges", "message"),
    [
        ({}, "ranges has no channel: give at least one of r, g, b"),
        ({"a": [0, 1]}, "ranges.a is not a channel: the channels are r, g and b"),
        ({"r": [0, 300]}, "ranges.r[1] = 300 must be between 0 and 255"),
        ({"g": [-1, 3]}, "ranges.g[0] = -1 must be between 0 and 255"),
        ({"b": [200, 100]}, "ranges.b: min 200 is more than max 100"),
        ({"r": [0, 1.5]}, "ranges.r[1] must be an integer"),
        ({"r": [0, 1, 2]}, "ranges.r must be a pair [min, max]"),
        ({"r": 5}, "ranges.r must be a pair [min, max]"),
        ([[0, 1]], "ranges must be an object {r, g, b} of [min, max] pairs"),
    ],
)
def test_malformed_ranges_are_refused(ranges: object, message: str) -> None:
    with pytest.raises(ImagingError) as error:
        fraction(halves(), ranges)  # type: ignore[arg-type]
    assert str(error.value) == message


@pytest.mark.parametrize(
    ("width", "height", "message"),
    [
        (0, 10, "width = 0 must be between 1 and 4096"),
        (10, 4097, "height = 4097 must be between 1 and 4096"),
        (2.5, 10, "width must be an integer"),
        (10, None, "height must be an integer"),
    ],
)
def test_a_bad_size_is_refused(width: object, height: object, message: str) -> None:
    with pytest.raises(ImagingError) as error:
        resize(halves(), width, height)  # type: ignore[arg-type]
    assert str(error.value) == message


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"not a picture at all",
        halves()[:60],  # cut off in its pixels
        png(Image.new("RGB", (4, 4))).replace(b"PNG", b"GIF"),
    ],
)
def test_bytes_that_are_not_a_readable_picture_are_refused(data: bytes) -> None:
    for call in (lambda: stats(data), lambda: crop(data, Region(0, 0, 1, 1))):
        with pytest.raises(ImagingError, match=r"^picture: not a readable PNG or JPEG image$"):
            call()


def test_a_gif_is_not_a_picture_an_image_call_reads() -> None:
    out = io.BytesIO()
    Image.new("RGB", (4, 4)).save(out, format="GIF")
    with pytest.raises(ImagingError, match="not a readable PNG or JPEG image"):
        stats(out.getvalue())


def test_a_picture_claiming_more_than_40_megapixels_is_refused_before_decoding() -> None:
    with pytest.raises(ImagingError) as error:
        stats(png_header(8000, 6000))
    assert str(error.value) == (
        "picture: 8000 x 6000 = 48,000,000 pixels is more than the 40,000,000 an image call reads"
    )
    # Beyond Pillow's own bomb limit, Pillow refuses at opening; the message says the same.
    with pytest.raises(ImagingError, match=r"^picture: larger than the 40,000,000 pixels"):
        resize(png_header(20000, 20000), 10, 10)
