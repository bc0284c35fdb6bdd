"""GET /tiles/{z}/{x}/{y}.png: the maps' background, served by the platform to anyone."""

from __future__ import annotations

import asyncio
import io
import threading
import time

import pytest
from django.test import RequestFactory
from django.urls import reverse
from PIL import Image
from rest_framework.throttling import SimpleRateThrottle

from fleet import views
from fleet.simulation.tiles import render_tile

# A tile over the paper's field (examples/scenarios): 48.111 N, 12.862 E.
FIELD_TILE = (16, 35109, 22750)

pytestmark = pytest.mark.django_db


def _url(z: int, x: int, y: int) -> str:
    return reverse("map-tile", kwargs={"z": z, "x": x, "y": y})


def test_a_tile_is_a_png_of_the_platforms_world_for_anyone_and_kept_a_day(client) -> None:
    response = client.get(_url(*FIELD_TILE))  # no login: a tile holds nothing secret
    assert response.status_code == 200
    assert response["Content-Type"] == "image/png"
    assert response["Cache-Control"] == "public, max-age=86400"
    assert Image.open(io.BytesIO(response.content)).size == (256, 256)
    # The world the workers' sensors and cameras read.
    assert response.content == render_tile(*FIELD_TILE, seed=views.PLATFORM_WORLD_SEED)


def test_a_tile_is_drawn_once_and_then_served_from_memory(client) -> None:
    views.platform_tile.cache_clear()
    first = client.get(_url(15, 17554, 11375)).content
    again = client.get(_url(15, 17554, 11375)).content
    assert first == again
    info = views.platform_tile.cache_info()
    assert (info.misses, info.hits) == (1, 1)
    assert info.maxsize == views.CACHED_TILES


@pytest.mark.parametrize(
    ("z", "x", "y", "reason"),
    [
        (22, 0, 0, "zoom 22 is outside 0..21"),
        (20, 0, 0, "the platform's maps are drawn to zoom 19 (and enlarged beyond)"),
        (0, 1, 0, "x = 1 is outside 0..0 at zoom 0"),
        (2, 0, 4, "y = 4 is outside 0..3 at zoom 2"),
        (21, 2**21, 0, "x = 2097152 is outside 0..2097151 at zoom 21"),
    ],
)
def test_an_address_outside_the_pyramid_is_a_404_saying_why(client, z, x, y, reason) -> None:
    response = client.get(_url(z, x, y))
    assert response.status_code == 404
    assert response["Content-Type"].startswith("text/plain")
    assert response.content.decode() == f"No map tile {z}/{x}/{y}: {reason}."


@pytest.mark.parametrize("path", ["/tiles/1/-1/0.png", "/tiles/a/0/0.png", "/tiles/1/0/0.jpg"])
def test_what_is_no_tile_address_at_all_is_a_404(client, path) -> None:
    assert client.get(path).status_code == 404


def test_a_tile_is_only_read(client) -> None:
    for method in ("post", "put", "delete"):
        assert getattr(client, method)("/tiles/0/0/0.png").status_code == 405


def test_a_client_over_its_tile_rate_is_told_when_to_come_back_and_others_are_served(
    client, monkeypatch
) -> None:
    rates = {**SimpleRateThrottle.THROTTLE_RATES, "tiles": "3/min"}
    monkeypatch.setattr(SimpleRateThrottle, "THROTTLE_RATES", rates)
    tiles = [(19, 280_878 + n, 182_000) for n in range(4)]  # deepest served, all different
    assert [client.get(_url(*t)).status_code for t in tiles[:3]] == [200, 200, 200]

    refused = client.get(_url(*tiles[3]))

    assert refused.status_code == 429
    assert 0 < int(refused["Retry-After"]) <= 60
    assert refused.content.decode() == (
        "Too many map tiles from your address (3/min): try again later."
    )
    # Another address has its own count.
    assert client.get(_url(*tiles[3]), REMOTE_ADDR="192.0.2.7").status_code == 200


async def test_a_crowd_of_new_tiles_is_drawn_a_few_at_a_time(monkeypatch) -> None:
    drawing, most, release = [0], [0], threading.Event()
    lock = threading.Lock()

    def slow_render(z: int, x: int, y: int, seed: int) -> bytes:
        with lock:
            drawing[0] += 1
            most[0] = max(most[0], drawing[0])
        release.wait(30)
        with lock:
            drawing[0] -= 1
        return b"png"

    monkeypatch.setattr(views, "render_tile", slow_render)
    views.platform_tile.cache_clear()
    factory = RequestFactory()
    # The view itself, eight requests at once (as an ASGI server without synchronous
    # middleware in front would call it).
    crowd = [
        asyncio.ensure_future(views.map_tile(factory.get("/"), 17, 70_000 + n, 45_500))
        for n in range(8)
    ]
    deadline = time.monotonic() + 30
    # Two drawing, six waiting their turn in the renderers' queue (not in threads of their own).
    while views._rendering._work_queue.qsize() < 6 and time.monotonic() < deadline:
        await asyncio.sleep(0.01)
    assert (most[0], views._rendering._work_queue.qsize()) == (views.RENDERERS, 6)
    release.set()
    answers = await asyncio.gather(*crowd)
    assert [a.status_code for a in answers] == [200] * 8 and most[0] == views.RENDERERS
    views.platform_tile.cache_clear()
