"""The fleet's pages outside the admin: the map tiles of the simulated world.

``GET /tiles/{z}/{x}/{y}.png`` is the background of every map (the live maps, a VV's map, the
admin's maps) when ``CPCC_MAP_TILES`` names no tile server: the world the simulated sensors and
cameras read (fleet/simulation/tiles.py), served by the platform itself, so the maps work
without the internet. A tile holds nothing but that seeded world: it needs no login, and a
browser and any proxy may keep it.
"""

from __future__ import annotations

import asyncio
import functools

from django.http import HttpRequest, HttpResponse, HttpResponseNotFound
from django.views.decorators.http import require_safe

from fleet.simulation.tiles import TileOutOfRange, check_tile, render_tile
from fleet.simulation.world import PLATFORM_WORLD_SEED  # what the workers' sensors read

# Tiles kept rendered in each web process: about 2 to 35 kB each (a few MB in all), enough
# for the views a few people look at; a tile costs 20 to 60 ms to draw again.
CACHED_TILES = 1_024
# The world changes only with the renderer: a day in the browsers and proxies.
CACHE_CONTROL = "public, max-age=86400"


@functools.lru_cache(maxsize=CACHED_TILES)
def platform_tile(z: int, x: int, y: int) -> bytes:
    """The PNG of tile z/x/y of the platform's world, from the cache when it was drawn before."""
    return render_tile(z, x, y, seed=PLATFORM_WORLD_SEED)


@require_safe
async def map_tile(request: HttpRequest, z: int, x: int, y: int) -> HttpResponse:
    """A 256 x 256 PNG; 404 with a plain-text reason for an address outside the pyramid."""
    try:
        check_tile(z, x, y)
    except TileOutOfRange as exc:
        return HttpResponseNotFound(f"No map tile {z}/{x}/{y}: {exc}.", content_type="text/plain")
    # Drawn in a thread of its own (NumPy and Pillow release the GIL for much of it): a map
    # asks for a dozen tiles at once, and Django's thread for synchronous views stays free.
    png = await asyncio.to_thread(platform_tile, z, x, y)
    response = HttpResponse(png, content_type="image/png")
    response["Cache-Control"] = CACHE_CONTROL
    return response
