"""Rendered camera images: real, deterministic files of the catalog's size, of a continuous world."""

import io
from datetime import UTC, datetime

import numpy as np
import pytest
from PIL import Image

from fleet.geo import Position, offset
from fleet.simulation import SensorSpec, render_camera
from fleet.simulation.camera import overlay_text

POSITION = Position(47.0707, 15.4395, 60.0)
FRONT = SensorSpec("Camera 640x480", "camera", params={"width": 640, "height": 480})
BELLY = SensorSpec(
    "Belly Mounted Camera 640x480", "camera", params={"width": 640, "height": 480, "view": "belly"}
)
FPV = SensorSpec("FPV Camera 640x480", "camera", params={"view": "fpv"})


def _open(data: bytes) -> Image.Image:
    image = Image.open(io.BytesIO(data))
    image.load()
    return image


def _pixels(data: bytes) -> np.ndarray:
    return np.asarray(_open(data).convert("RGB"), dtype=np.float64)


def _mean_difference(a: bytes, b: bytes) -> float:
    return float(np.abs(_pixels(a) - _pixels(b)).mean())


@pytest.mark.parametrize("sensor", [FRONT, BELLY, FPV])
def test_image_is_a_png_of_the_catalog_size(sensor: SensorSpec) -> None:
    image = _open(render_camera(sensor, POSITION, 12.0, seed=1))
    assert image.format == "PNG"
    assert image.size == (640, 480)
    assert image.mode == "RGB"


def test_jpeg_format_and_custom_size_are_honoured() -> None:
    sensor = SensorSpec("Small", "camera", params={"width": 320, "height": 200, "format": "jpeg"})
    image = _open(render_camera(sensor, POSITION, 0.0, seed=1))
    assert image.format == "JPEG"
    assert image.size == (320, 200)


@pytest.mark.parametrize("sensor", [FRONT, BELLY])
def test_same_inputs_give_identical_bytes(sensor: SensorSpec) -> None:
    first = render_camera(sensor, POSITION, 12.0, seed=5, heading_deg=40.0)
    again = render_camera(
        SensorSpec(sensor.name, "camera", params=dict(sensor.params)),
        Position(POSITION.lat, POSITION.lng, POSITION.alt),
        12.0,
        seed=5,
        heading_deg=40.0,
    )
    assert first == again


@pytest.mark.parametrize("sensor", [FRONT, BELLY])
def test_points_200_m_apart_give_different_pictures(sensor: SensorSpec) -> None:
    here = render_camera(sensor, POSITION, 0.0, seed=2)
    there = render_camera(sensor, offset(POSITION, north_m=200.0, east_m=0.0), 0.0, seed=2)
    assert _mean_difference(here, there) > 5.0


def test_nearby_points_give_related_pictures() -> None:
    # The world is continuous: a 1 m step barely changes a view 84 m wide, 200 m changes it all.
    here = render_camera(BELLY, POSITION, 0.0, seed=2)
    step = render_camera(BELLY, offset(POSITION, north_m=1.0, east_m=0.0), 0.0, seed=2)
    far = render_camera(BELLY, offset(POSITION, north_m=200.0, east_m=0.0), 0.0, seed=2)
    assert _mean_difference(here, step) < _mean_difference(here, far) / 3.0


def test_belly_and_front_views_differ() -> None:
    belly = render_camera(BELLY, POSITION, 0.0, seed=3)
    front = render_camera(FRONT, POSITION, 0.0, seed=3)
    assert _mean_difference(belly, front) > 10.0


def test_front_view_shows_sky_above_ground() -> None:
    pixels = _pixels(render_camera(FRONT, POSITION, 0.0, seed=3))
    top, bottom = pixels[60:100], pixels[-40:]
    # Sky is bluer than it is red; the ground near the camera is not.
    assert (top[..., 2] - top[..., 0]).mean() > 30.0
    assert (bottom[..., 2] - bottom[..., 0]).mean() < (top[..., 2] - top[..., 0]).mean()


def test_belly_footprint_is_proportional_to_altitude() -> None:
    # From twice as high, the centre half of the picture is the lower picture shrunk by two.
    low = _open(render_camera(BELLY, POSITION.with_alt(100.0), 0.0, seed=4)).convert("RGB")
    high = _open(render_camera(BELLY, POSITION.with_alt(200.0), 0.0, seed=4)).convert("RGB")
    low_shrunk = np.asarray(low.resize((320, 240), Image.Resampling.BOX), dtype=np.float64)
    high_centre = np.asarray(high.crop((160, 120, 480, 360)), dtype=np.float64)
    high_shrunk = np.asarray(high.resize((320, 240), Image.Resampling.BOX), dtype=np.float64)
    below_caption = slice(40, None)
    matched = np.abs(low_shrunk - high_centre)[below_caption].mean()
    unscaled = np.abs(low_shrunk - high_shrunk)[below_caption].mean()
    assert matched < 3.0
    assert matched < unscaled / 4.0


def test_seed_and_heading_change_the_picture() -> None:
    base = render_camera(BELLY, POSITION, 0.0, seed=1)
    assert _mean_difference(base, render_camera(BELLY, POSITION, 0.0, seed=2)) > 5.0
    turned = render_camera(BELLY, POSITION, 0.0, seed=1, heading_deg=90.0)
    assert _mean_difference(base, turned) > 5.0


def test_bad_camera_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="not a camera"):
        render_camera(SensorSpec("CO2", "scalar", params={"quantity": "co2"}), POSITION, 0, seed=1)
    with pytest.raises(ValueError, match="format"):
        render_camera(SensorSpec("C", "camera", params={"format": "gif"}), POSITION, 0, seed=1)
    with pytest.raises(ValueError, match="width"):
        render_camera(SensorSpec("C", "camera", params={"width": 0}), POSITION, 0, seed=1)


def test_the_caption_prints_the_utc_date_and_time_not_epoch_seconds() -> None:
    epoch_s = datetime(2026, 11, 27, 13, 4, 5, 900_000, tzinfo=UTC).timestamp()
    text = overlay_text("Camera 640x480", Position(48.11112345, 12.8619, 50.04), epoch_s)
    # To the second, as a clock shows it (not rounded up to :06).
    assert text.splitlines() == [
        "Camera 640x480",
        "48.111123, 12.861900  alt 50.0 m",
        "2026-11-27 13:04:05 UTC",
    ]
    assert str(int(epoch_s)) not in text


def test_a_picture_carries_the_time_it_is_given_to_print() -> None:
    # A simulation's clock counts from 0: the reading's date is printed, not "1970-01-01".
    first = render_camera(BELLY, POSITION, 12.0, seed=1, epoch_s=1_735_689_612.0)
    assert first == render_camera(BELLY, POSITION, 12.0, seed=1, epoch_s=1_735_689_612.4)
    assert first != render_camera(BELLY, POSITION, 12.0, seed=1, epoch_s=1_735_689_613.0)
    # Without one it prints time_s, the Unix epoch in a live system.
    assert render_camera(BELLY, POSITION, 12.0, seed=1) == render_camera(
        BELLY, POSITION, 12.0, seed=1, epoch_s=12.0
    )
    with pytest.raises(ValueError, match="epoch_s"):
        render_camera(BELLY, POSITION, 12.0, seed=1, epoch_s=float("nan"))
