"""The live map's socket: a snapshot first, then frames with what changed.

Each socket reads the feed (missions/events.py) itself: it blocks on the changes stream and the
positions stream, and sends its browser one frame with what came (filtered for its user), then
waits a batch interval (CPCC_MAP_BATCH_S) so that whatever arrives meanwhile goes in the next
frame. A browser that connects (or reconnects, or asks with ``{"type": "resync"}``) gets a
snapshot of the database (and ``now``, the time on the platform's clock) and then frames from
the point the snapshot was taken; a socket that fell behind the changes stream's window sends
a new snapshot. Frames are numbered (``seq``) per socket.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from typing import Any
from urllib.parse import parse_qs

import redis.asyncio as aioredis
from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer
from django.conf import settings

from cpcc_site import json_depth
from missions.events import (
    EVENTS_STREAM,
    POSITIONS_STREAM,
    VEHICLE_STALE_S,
    VEHICLES_HASH,
    carrier_id,
    event_for,
    vehicle_for,
)
from missions.selectors import VVNotFound, map_snapshot_for_user

logger = logging.getLogger("cpcc.map")

# Close codes: the page shows why and does not reconnect for these.
NOT_ALLOWED = 4403
NOT_FOUND = 4404
MAX_ENTRIES_PER_READ = 5_000
BLOCK_MS = 5_000


class MapConsumer(AsyncJsonWebsocketConsumer):  # type: ignore[misc]
    """``/ws/map/`` (``?vv=<id>`` for one VV): the live map of the user's VVs (all for staff)."""

    # Nothing comes to this socket through the channel layer (it reads the feed itself), so
    # it joins none: an alias no layer is configured under.
    channel_layer_alias = "none"

    async def connect(self) -> None:
        user = self.scope.get("user")
        if user is None or not user.is_authenticated:
            await self.close(code=NOT_ALLOWED)
            return
        if not (user.is_staff or user.customer_id):
            await self.close(code=NOT_ALLOWED)
            return
        self.user = user
        self.staff = bool(user.is_staff)
        self.customer_id = user.customer_id
        query = parse_qs(self.scope.get("query_string", b"").decode())
        self.vv_id = (query.get("vv") or [None])[0]
        # A blocking read waits up to BLOCK_MS: the socket's own timeout must be longer.
        self.redis = aioredis.Redis.from_url(
            settings.CPCC_FEED_REDIS_URL, socket_timeout=BLOCK_MS / 1000 + 5
        )
        self.seq = 0
        self.shown: dict[str, float] = {}
        try:
            snapshot = await self._snapshot()
        except VVNotFound:
            await self.close(code=NOT_FOUND)
            await self.redis.aclose()
            return
        await self.accept()
        await self.send_json(snapshot)
        self.pump = asyncio.create_task(self._pump())

    async def disconnect(self, code: int) -> None:
        pump = getattr(self, "pump", None)
        if pump is not None:
            pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await pump
        if hasattr(self, "redis"):
            await self.redis.aclose()

    async def receive(
        self, text_data: str | None = None, bytes_data: bytes | None = None, **kwargs: Any
    ) -> None:
        # What a browser sends is parsed with the platform's depth limit, and a message that
        # is not JSON answers an error frame instead of ending the socket with a server error.
        try:
            content = json_depth.loads(text_data or "")
        except ValueError as exc:
            detail = (
                str(exc)
                if isinstance(exc, json_depth.TooDeep)
                else 'The message is not JSON text: send {"type": "resync"} for the whole map.'
            )
            await self.send_json({"type": "error", "detail": detail})
            return
        await self.receive_json(content, **kwargs)

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        if isinstance(content, dict) and content.get("type") == "resync":
            await self.send_json(await self._snapshot())

    # --- what is sent ----------------------------------------------------------------------

    async def _snapshot(self) -> dict[str, Any]:
        # The streams' positions are read before the database, so nothing that commits in
        # between is missed (a change may come twice: applying it twice is harmless).
        self.cursors = {
            EVENTS_STREAM: await self._last_id(EVENTS_STREAM),
            POSITIONS_STREAM: await self._last_id(POSITIONS_STREAM),
        }
        data = await database_sync_to_async(map_snapshot_for_user)(user=self.user, vv_id=self.vv_id)
        states = await self.redis.hgetall(VEHICLES_HASH)
        self.shown: dict[str, float] = {}
        vehicles = self._visible(json.loads(raw) for raw in states.values())
        self.seq += 1
        # "now" on the platform's clock: the page's time window counts back from it, whatever
        # the browser's own clock says.
        return {
            "type": "snapshot",
            "seq": self.seq,
            "now": time.time(),
            **data,
            "vehicles": vehicles,
        }

    async def _last_id(self, stream: str) -> str:
        last = await self.redis.xrevrange(stream, count=1)
        return last[0][0].decode() if last else "0-0"

    async def _pump(self) -> None:
        while True:
            try:
                frame = await self._next_frame()
            except asyncio.CancelledError:
                raise
            except Exception:
                logger.exception("live map: frame failed")
                await asyncio.sleep(1.0)
                continue
            if frame is not None:
                await self.send_json(frame)
            await asyncio.sleep(settings.CPCC_MAP_BATCH_S)

    async def _next_frame(self) -> dict[str, Any] | None:
        read = await self.redis.xread(self.cursors, count=MAX_ENTRIES_PER_READ, block=BLOCK_MS)
        entries = {name.decode(): got for name, got in read or ()}
        changes = entries.get(EVENTS_STREAM, [])
        if len(changes) >= MAX_ENTRIES_PER_READ or await self._fell_behind():
            return await self._snapshot()
        events = []
        for entry_id, fields in changes:
            self.cursors[EVENTS_STREAM] = entry_id.decode()
            event = event_for(
                json.loads(fields[b"e"]), customer_id=self.customer_id, staff=self.staff
            )
            if event is not None and (self.vv_id is None or event.get("vv") == self.vv_id):
                events.append(event)
        latest: dict[Any, dict[str, Any]] = {}
        for entry_id, fields in entries.get(POSITIONS_STREAM, []):
            self.cursors[POSITIONS_STREAM] = entry_id.decode()
            state = json.loads(fields[b"v"])
            latest[state["id"]] = state  # a later position supersedes an earlier one
        vehicles = self._visible(latest.values())
        gone = self._gone()
        if not (events or vehicles or gone):
            return None
        self.seq += 1
        return {
            "type": "frame",
            "seq": self.seq,
            "events": events,
            "vehicles": vehicles,
            "gone": gone,
        }

    async def _fell_behind(self) -> bool:
        """Whether changes this socket has not read were trimmed from the stream."""
        cursor = self.cursors[EVENTS_STREAM]
        if cursor == "0-0":
            return False
        first = await self.redis.xrange(EVENTS_STREAM, count=1)
        return bool(first) and _older(cursor, first[0][0].decode())

    def _visible(self, states: Any) -> list[dict[str, Any]]:
        """The vehicles of ``states`` this socket shows, as its user may see them."""
        now = time.time()
        shown = []
        for state in states:
            if now - float(state.get("t") or 0) > VEHICLE_STALE_S:
                continue
            visible = vehicle_for(
                state, customer_id=self.customer_id, staff=self.staff, secret=settings.SECRET_KEY
            )
            if visible is None:
                self._hide(str(state["id"]), state)
                continue
            if self.vv_id is not None and not any(
                vv["id"] == self.vv_id for vv in visible.get("vvs", ())
            ):
                self._hide(str(state["id"]), state)
                continue
            self.shown[str(visible["id"])] = float(visible.get("t") or now)
            shown.append(visible)
        return shown

    def _hide(self, vehicle_id: str, state: dict[str, Any]) -> None:
        """A vehicle this socket showed that no longer carries what its user may see."""
        key = vehicle_id if self.staff else carrier_id(int(vehicle_id), settings.SECRET_KEY)
        if key in self.shown:
            self.shown[key] = 0.0  # reported gone with the next frame

    def _gone(self) -> list[str]:
        """Vehicles shown before that left the user's view or stopped reporting."""
        now = time.time()
        gone = sorted(k for k, t in self.shown.items() if now - t > VEHICLE_STALE_S)
        for key in gone:
            del self.shown[key]
        return gone


def _older(a: str, b: str) -> bool:
    """Whether stream id ``a`` comes before ``b``."""
    ma, sa = (int(x) for x in a.split("-"))
    mb, sb = (int(x) for x in b.split("-"))
    return (ma, sa) < (mb, sb)
