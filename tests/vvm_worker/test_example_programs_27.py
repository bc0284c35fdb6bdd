"""The examples of issue 27 (examples/scenarios/messages-and-images.json) do what they say:
two VVs split a survey and exchange summaries of their halves, and a VV finds the greenest of
its pictures and looks closer at those spots."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from django.db import transaction
from django.test import override_settings
from PIL import Image

from tests.conftest import SCENARIOS
from vvm_worker.scenario import load_scenario
from vvm_worker.simulation import Simulation

# The tests read the module's one run (``summary``), which the database setup serves.
pytestmark = pytest.mark.django_db

SURVEY = ("survey-west", "survey-east")
# Heli One serves the west of 12.864, Heli Two the east (the scenario's areas).
BORDER_LNG = 12.864
# examples/vv/vegetation.js: what it counts as green, and where it looks in a picture.
GREEN = {"r": (0, 130), "g": (60, 255), "b": (0, 90)}
CHANNELS = {"r": 0, "g": 1, "b": 2}


@pytest.fixture(scope="module")
def summary(
    django_db_setup: None, django_db_blocker: Any, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[dict[str, Any]]:
    """The scenario simulated once for the module (as ``manage.py simulate --speed 0`` runs
    it), in a transaction rolled back at the end; its pictures stay in a folder of their own."""
    media = tmp_path_factory.mktemp("example-programs-media")
    with (
        django_db_blocker.unblock(),
        transaction.atomic(),
        override_settings(MEDIA_ROOT=media),
    ):
        yield Simulation(load_scenario(SCENARIOS / "messages-and-images.json")).run()
        transaction.set_rollback(True)


def vv(summary: dict[str, Any], name: str) -> dict[str, Any]:
    (found,) = [v for v in summary["vvs"] if v["name"] == name]
    return dict(found)


def pixels(picture: dict[str, Any]) -> np.ndarray:
    """The RGB pixels of a picture in the summary (its ``image`` is the file's path)."""
    with Image.open(picture["image"]) as image:
        return np.asarray(image.convert("RGB"), dtype=np.int64)


def green_fraction(rgb: np.ndarray) -> float:
    inside = np.ones(rgb.shape[:2], dtype=bool)
    for channel, (low, high) in GREEN.items():
        values = rgb[..., CHANNELS[channel]]
        inside &= (values >= low) & (values <= high)
    return float(inside.mean())


def test_every_vv_of_the_scenario_finishes(summary: dict[str, Any]) -> None:
    assert {v["name"]: (v["status"], v["error"]) for v in summary["vvs"]} == {
        "survey-west": ("finished", None),
        "survey-east": ("finished", None),
        "vegetation": ("finished", None),
    }


def test_each_survey_vv_measures_its_half_and_keeps_the_others_summary(
    summary: dict[str, Any],
) -> None:
    for name, other in (SURVEY, SURVEY[::-1]):
        me = vv(summary, name)
        assert me["tasks_done"] == 6
        west = name == "survey-west"
        assert all((t["position"][1] < BORDER_LNG) == west for t in me["tasks"])
        storage = me["storage"]
        points = [storage[f"point.{k}"] for k in range(6)]
        mine = storage[f"summary.{name}"]
        assert mine["by"] == name and mine["points"] == 6
        for field in ("temperature", "nox"):
            values = [p[field] for p in points]
            assert mine[field]["max"] == max(values)
            hottest = next(p for p in points if p[field] == max(values))
            assert mine[field]["at"] == {"lat": hottest["lat"], "lng": hottest["lng"]}
            assert mine[field]["mean"] == pytest.approx(sum(values) / 6, abs=0.01)  # 2 decimals
        # What the other VV sent is what it stored as its own summary: received, and once.
        assert storage[f"summary.{other}"] == vv(summary, other)["storage"][f"summary.{other}"]
        assert sorted(storage) == sorted(
            [*(f"point.{k}" for k in range(6)), f"summary.{name}", f"summary.{other}", "hottest"]
        )


def test_both_survey_vvs_name_the_hottest_point_of_the_whole_grid(
    summary: dict[str, Any],
) -> None:
    points = [
        (p["temperature"], p["lat"], p["lng"], name)
        for name in SURVEY
        for key, p in vv(summary, name)["storage"].items()
        if key.startswith("point.")
    ]
    # On a tie between the halves both name the same VV, the one whose name sorts first.
    temperature, lat, lng, by = max(points, key=lambda p: (p[0], p[3] == min(SURVEY)))
    expected = {"temperature": temperature, "at": {"lat": lat, "lng": lng}, "by": by}
    assert vv(summary, "survey-west")["storage"]["hottest"] == expected
    assert vv(summary, "survey-east")["storage"]["hottest"] == expected


def test_the_vegetation_vv_goes_back_to_its_three_greenest_spots_at_20_m(
    summary: dict[str, Any],
) -> None:
    veg = vv(summary, "vegetation")
    storage = veg["storage"]
    grid = [storage[f"grid.{k}"] for k in range(9)]
    # Each measure is the green share of the lower half of the picture (the ground).
    for spot in grid:
        rgb = pixels(spot["picture"])
        assert spot["green"] == pytest.approx(green_fraction(rgb[rgb.shape[0] // 2 :]), abs=1e-6)
    greens = [spot["green"] for spot in grid]
    assert max(greens) > min(greens)  # the grid sees different ground
    greenest = sorted(range(9), key=lambda k: (-greens[k], k))[:3]
    assert storage["greenest"] == greenest
    assert sorted(k for k in storage if k.startswith("closeup.")) == sorted(
        f"closeup.{k}" for k in greenest
    )
    # 9 pictures from 60 m, then one from 20 m above each of the greenest, greenest first.
    assert veg["tasks_done"] == 12
    assert [t["position"][2] for t in veg["tasks"]] == [60] * 9 + [20] * 3
    for task, k in zip(veg["tasks"][9:], greenest, strict=True):
        spot = grid[k]["position"]
        assert task["position"] == [spot["lat"], spot["lng"], 20]


def test_each_close_up_is_a_crop_of_the_ground_just_ahead_with_its_stats_and_a_thumbnail(
    summary: dict[str, Any],
) -> None:
    storage = vv(summary, "vegetation")["storage"]
    for k in storage["greenest"]:
        closeup = storage[f"closeup.{k}"]
        close = pixels(closeup["picture"])
        assert close.shape == (480, 640, 3)
        assert closeup["greenFrom60m"] == storage[f"grid.{k}"]["green"]
        # The bottom centre: a third of the width, a quarter of the height.
        detail = closeup["detail"]
        assert (detail["width"], detail["height"], detail["format"]) == (213, 120, "png")
        assert Path(detail["image"]).suffix == ".png"
        assert detail["position"] == closeup["picture"]["position"]
        np.testing.assert_array_equal(pixels(detail), close[360:480, 213:426])
        stats = closeup["stats"]
        assert (stats["width"], stats["height"]) == (213, 120)
        for channel, c in CHANNELS.items():
            values = close[360:480, 213:426, c]
            assert stats["mean"][channel] == pytest.approx(values.mean(), abs=1e-5)
            assert stats["std"][channel] == pytest.approx(values.std(), abs=1e-5)
        assert closeup["green"] == pytest.approx(green_fraction(close[360:480, 213:426]), abs=1e-6)
        thumbnail = closeup["thumbnail"]
        assert (thumbnail["width"], thumbnail["height"]) == (160, 120)
        with Image.open(closeup["picture"]["image"]) as source:
            expected = source.convert("RGB").resize((160, 120), Image.Resampling.BILINEAR)
        np.testing.assert_array_equal(pixels(thumbnail), np.asarray(expected, dtype=np.int64))
