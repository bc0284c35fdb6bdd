"""The fleet's pages outside the admin: the map tiles of the simulated world.

``GET /tiles/{z}/{x}/{y}.png`` is the background of every map (the live maps, a VV's map, the
admin's maps) when ``CPCC_MAP_TILES`` names no tile server: the world the simulated sensors and
cameras read (fleet/simulation/tiles.py), served by the platform itself, so the maps work
without the internet. A tile holds nothing but that seeded world: it needs no login, and a
browser and any proxy may keep it.

Being public, it is bounded: each client address may ask for ``CPCC_TILE_RATE`` tiles (429
beyond, counted in Redis for every web process, as the API's rates are); the maps enlarge
zoom 19's tiles beyond it, so deeper ones are not drawn; and each process draws at most
RENDERERS tiles at once, so a crowd of new tiles waits its turn instead of taking the
process's threads from everyone else's requests.
"""

from __future__ import annotations

import asyncio
import functools
import math
from concurrent.futures import ThreadPoolExecutor

from django.http import HttpRequest, HttpResponse, HttpResponseNotFound
from django.views.decorators.http import require_safe

from cpcc_site.throttling import TileRateThrottle
from fleet.simulation.tiles import TileOutOfRange, check_tile, render_tile
from fleet.simulation.world import PLATFORM_WORLD_SEED  # what the workers' sensors read

# Tiles kept rendered in each web process: about 2 to 35 kB each (a few MB in all), enough
# for the views a few people look at; a tile costs 20 to 60 ms to draw again.
CACHED_TILES = 1_024
# The world changes only with the renderer: a day in the browsers and proxies.
CACHE_CONTROL = "public, max-age=86400"
# The deepest tiles served: the maps (static/js/map.js, admin/map-common.js) enlarge these
# for zoom 20 and 21 (a pixel is 30 cm here, finer than any reading's position).
SERVED_MAX_ZOOM = 19
# Tiles drawn at once in a web process.
RENDERERS = 2
_rendering = ThreadPoolExecutor(max_workers=RENDERERS, thread_name_prefix="tiles")


@functools.lru_cache(maxsize=CACHED_TILES)
def platform_tile(z: int, x: int, y: int) -> bytes:
    """The PNG of tile z/x/y of the platform's world, from the cache when it was drawn before."""
    return render_tile(z, x, y, seed=PLATFORM_WORLD_SEED)


@require_safe
async def map_tile(request: HttpRequest, z: int, x: int, y: int) -> HttpResponse:
    """A 256 x 256 PNG; 404 with a plain-text reason for an address outside the pyramid or
    deeper than SERVED_MAX_ZOOM; 429 (with Retry-After) for a client over its rate."""
    try:
        check_tile(z, x, y)
        if z > SERVED_MAX_ZOOM:
            raise TileOutOfRange(
                f"the platform's maps are drawn to zoom {SERVED_MAX_ZOOM} (and enlarged beyond)"
            )
    except TileOutOfRange as exc:
        return HttpResponseNotFound(f"No map tile {z}/{x}/{y}: {exc}.", content_type="text/plain")
    throttle = TileRateThrottle()
    if not await asyncio.to_thread(throttle.allow_request, request, None):
        wait_s = throttle.wait()
        refused = HttpResponse(
            f"Too many map tiles from your address ({throttle.rate}): try again later.",
            status=429,
            content_type="text/plain",
        )
        if wait_s is not None:
            refused["Retry-After"] = str(max(1, math.ceil(wait_s)))
        return refused
    # Drawn in one of RENDERERS threads (NumPy and Pillow release the GIL for much of it): a
    # map asks for a dozen tiles at once, and Django's thread for synchronous views stays free.
    png = await asyncio.get_running_loop().run_in_executor(_rendering, platform_tile, z, x, y)
    response = HttpResponse(png, content_type="image/png")
    response["Cache-Control"] = CACHE_CONTROL
    return response
