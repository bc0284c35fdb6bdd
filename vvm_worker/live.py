"""The live map's feed as the workers write it (missions/events.py says what it is).

`FeedAnnouncer` appends the changes the services announce to a Redis stream once their
transaction commits; `publish_vehicle` keeps an RV's latest state in a Redis hash. Redis being
away costs the map its updates, never the platform its work: failures are logged and dropped,
and a browser that reconnects starts again from a snapshot of the database.
"""

from __future__ import annotations

import functools
import json
import logging
import queue
import threading
import time
from typing import Any

import redis
from django.conf import settings
from django.db import transaction

from missions.events import (
    EVENTS_STREAM,
    POSITIONS_MAXLEN,
    POSITIONS_STREAM,
    STREAM_MAXLEN,
    VEHICLES_HASH,
)

logger = logging.getLogger("cpcc.live")

# A background publisher sends at most one round trip to Redis this often; what comes in
# meanwhile waits and goes with the next. A busy RV worker's pieces of work (hundreds a second)
# then cost Redis, and the worker's other threads, a few dozen wake-ups a second; a map is
# told 50 ms later at most.
PUBLISH_INTERVAL_S = 0.05


def feed_client() -> redis.Redis:
    """A client (with its connection pool) of the Redis that carries the feed."""
    return _client_for(settings.CPCC_FEED_REDIS_URL)


@functools.cache
def _client_for(url: str) -> redis.Redis:
    return redis.Redis.from_url(url, socket_timeout=1.0, socket_connect_timeout=1.0)


class FeedAnnouncer:
    """Publishes announced changes after their transaction commits (at once outside one).

    ``batched`` (an RV worker's host thread): what commits is kept until ``flush``, which the
    host calls after each piece of work, and then published in one round trip to Redis
    however many changes the piece made (a task's answer makes three to five).

    ``in_background`` (with ``batched``): ``flush`` hands what committed to a publisher thread
    and returns at once, so the host thread never waits for Redis; the publisher sends all
    that waits in one pipeline, in the order it committed, at most once every
    PUBLISH_INTERVAL_S. ``close`` publishes what is left and stops the thread."""

    def __init__(
        self,
        client: redis.Redis | None = None,
        *,
        batched: bool = False,
        in_background: bool = False,
    ) -> None:
        self._client = client
        self._batched = batched
        self._committed: list[str] = []
        self._in_background = in_background
        if in_background and not batched:
            raise ValueError("a feed published in the background is batched")
        self._outbox: queue.SimpleQueue[list[str] | None] = queue.SimpleQueue()
        self._publisher: threading.Thread | None = None  # started with the first flush
        self._published = 0

    def announce(self, event: dict[str, Any]) -> None:
        data = json.dumps(event, separators=(",", ":"))
        if self._batched:
            # Each change its own hook: one rolled back with a savepoint is never kept.
            transaction.on_commit(lambda: self._committed.append(data))
        else:
            transaction.on_commit(lambda: self._publish([data]), robust=True)

    @property
    def published(self) -> int:
        """How many changes were handed to Redis so far (a host's look at whether anything
        changed since it last looked)."""
        return self._published

    def flush(self) -> None:
        """Publish the changes that committed since the last flush, in one pipeline."""
        if not self._committed:
            return
        committed, self._committed = self._committed, []
        self._published += len(committed)
        if not self._in_background:
            self._publish(committed)
            return
        if self._publisher is None:
            self._publisher = threading.Thread(
                target=self._publish_waiting, name="cpcc-feed", daemon=True
            )
            self._publisher.start()
        self._outbox.put(committed)

    def close(self, timeout_s: float = 5.0) -> None:
        """Publish what waits, then stop the publisher (if any)."""
        self.flush()
        if self._publisher is not None:
            self._outbox.put(None)
            self._publisher.join(timeout_s)
            self._publisher = None

    def _publish_waiting(self) -> None:
        outbox = self._outbox
        published_at = float("-inf")
        while True:
            events = outbox.get()
            pause = published_at + PUBLISH_INTERVAL_S - time.monotonic()
            if pause > 0 and events is not None:
                time.sleep(pause)  # what else comes in meanwhile goes in the same round trip
            stop = events is None
            waiting = list(events or [])
            while not stop:  # whatever else waits goes in the same round trip
                try:
                    more = outbox.get_nowait()
                except queue.Empty:
                    break
                if more is None:
                    stop = True
                else:
                    waiting.extend(more)
            if waiting:
                self._publish(waiting)
                published_at = time.monotonic()
            if stop:
                return

    def _publish(self, events: list[str]) -> None:
        if not self._batched:
            self._published += len(events)
        pipe = (self._client or feed_client()).pipeline(transaction=False)
        for data in events:
            pipe.xadd(EVENTS_STREAM, {"e": data}, maxlen=STREAM_MAXLEN, approximate=True)
        try:
            pipe.execute()
        except redis.RedisError as exc:
            logger.warning("live map: %d change(s) not published: %s", len(events), exc)


def publish_vehicle(state: dict[str, Any], client: redis.Redis | None = None) -> None:
    """Tell the maps an RV's state (position, VVs aboard, planned route): appended to the
    positions stream for the sockets, kept as the latest in the hash for snapshots."""
    data = json.dumps(state, separators=(",", ":"))
    try:
        pipe = (client or feed_client()).pipeline(transaction=False)
        pipe.hset(VEHICLES_HASH, str(state["id"]), data)
        pipe.xadd(POSITIONS_STREAM, {"v": data}, maxlen=POSITIONS_MAXLEN, approximate=True)
        pipe.execute()
    except redis.RedisError as exc:
        logger.warning("live map: vehicle state not published: %s", exc)
