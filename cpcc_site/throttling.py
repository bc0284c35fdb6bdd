"""The API's request rates, counted once for every web process.

DRF's throttles keep each client's recent requests in Django's cache, which is memory of its
own in each process: N web processes would allow N times the rate. These keep them in Redis
(``CPCC_THROTTLE_REDIS_URL``: REDIS_URL's server, or the embedded one), one sorted set of
request times per client and scope, checked and updated by one Lua script, so that two
processes cannot both take the last request a window allows. The rule is DRF's: at most N
requests in any window of the rate's duration, a refused request not counted.

While Redis does not answer, each process counts alone in its own cache (DRF's own way), says
so in its log, and asks Redis again after RETRY_S: a rate limit is no reason to refuse service.
"""

from __future__ import annotations

import functools
import logging
import os
import threading
import time
from typing import Any

import redis
from django.conf import settings
from redis.commands.core import Script
from rest_framework.request import Request
from rest_framework.throttling import BaseThrottle, SimpleRateThrottle
from rest_framework.throttling import UserRateThrottle as DRFUserRateThrottle

logger = logging.getLogger("cpcc.web")

KEY_PREFIX = "cpcc:"  # before DRF's key (throttle_SCOPE_IDENT)
RETRY_S = 5.0  # how long a process counts alone after Redis failed it
_TIMEOUT_S = 0.5  # a request waits no longer than this for Redis

# KEYS: the request times of each (client, scope); ARGV: now, then for each key its duration
# (s), limit and a unique member. Returns for each key {1, count} when the request is allowed
# there (and counted), {0, count, oldest time} when it is not.
_HIT = """
local now = tonumber(ARGV[1])
local answers = {}
for i, key in ipairs(KEYS) do
  local duration = tonumber(ARGV[3 * i - 1])
  redis.call('ZREMRANGEBYSCORE', key, '-inf', now - duration)
  local count = redis.call('ZCARD', key)
  if count < tonumber(ARGV[3 * i]) then
    redis.call('ZADD', key, now, ARGV[3 * i + 1])
    redis.call('PEXPIRE', key, math.ceil(duration * 1000))
    answers[i] = {1, count + 1}
  else
    local oldest = redis.call('ZRANGE', key, 0, 0, 'WITHSCORES')
    answers[i] = {0, count, oldest[2]}
  end
end
return answers
"""


@functools.cache
def _client_for(url: str) -> redis.Redis:
    return redis.Redis.from_url(url, socket_timeout=_TIMEOUT_S, socket_connect_timeout=_TIMEOUT_S)


def throttle_client() -> redis.Redis:
    """A client (with its connection pool) of the Redis that holds the counts."""
    return _client_for(settings.CPCC_THROTTLE_REDIS_URL)


# Sent once per Redis server, then called by its digest (EVALSHA) with any client.
_script = Script(None, _HIT.encode())  # type: ignore[arg-type]


class _Outage:
    """Until when this process counts alone after Redis failed it, so that it does not wait
    for a dead Redis on every request."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.until = 0.0

    def skip(self) -> bool:
        return time.monotonic() < self.until

    def failed(self, exc: Exception) -> None:
        with self._lock:
            if self.skip():
                return
            self.until = time.monotonic() + RETRY_S
        logger.warning(
            "request rates counted in this process alone for %g s: Redis did not answer (%s)",
            RETRY_S,
            exc,
        )


OUTAGE = _Outage()


def hit(
    client: redis.Redis, key: str, *, now: float, duration: float, limit: int
) -> tuple[bool, float | None]:
    """Count a request against ``limit`` requests in ``duration`` seconds: (allowed, time of
    the oldest request counted when refused). Raises redis.RedisError."""
    return hit_all(client, [(key, duration, limit)], now=now)[0]


def hit_all(
    client: redis.Redis, limits: list[tuple[str, float, int]], *, now: float
) -> list[tuple[bool, float | None]]:
    """``hit`` for each (key, duration, limit), in one round trip to Redis."""
    args: list[Any] = [now]
    for _, duration, limit in limits:
        args += [duration, limit, f"{now!r}:{os.urandom(6).hex()}"]
    keys = [KEY_PREFIX + key for key, _, _ in limits]
    answers = _script(keys=keys, args=args, client=client)
    return [(True, None) if int(a[0]) == 1 else (False, float(a[2])) for a in answers]


def forget_all(client: redis.Redis) -> None:
    """Forget every count (tests start from zero)."""
    for key in client.scan_iter(f"{KEY_PREFIX}throttle_*", count=1000):
        client.delete(key)


class SharedRateThrottle(SimpleRateThrottle):
    """A DRF rate throttle whose counts every web process shares (see the module)."""

    _oldest: float | None = None

    def allow_request(self, request: Request, view: Any) -> bool:
        if self.rate is None or OUTAGE.skip():
            return super().allow_request(request, view)  # type: ignore[no-any-return]
        self.key = self.get_cache_key(request, view)
        if self.key is None:
            return True
        self.now = self.timer()
        try:
            allowed, self._oldest = hit(
                throttle_client(),
                self.key,
                now=self.now,
                duration=self.duration,
                limit=self.num_requests,
            )
        except redis.RedisError as exc:
            OUTAGE.failed(exc)
            return super().allow_request(request, view)  # type: ignore[no-any-return]
        return allowed

    def wait(self) -> float | None:
        if self._oldest is None:  # counted in this process
            return super().wait()  # type: ignore[no-any-return]
        # One more request is allowed once the oldest one counted leaves the window.
        return max(self.duration - (self.now - self._oldest), 0.0)  # type: ignore[no-any-return]


class UserRateThrottle(SharedRateThrottle, DRFUserRateThrottle):
    """Requests per user (the "user" rate), the address for anonymous ones."""


class AddressRateThrottle(SharedRateThrottle):
    """Requests per client address, whoever sends them (the "address" rate)."""

    scope = "address"

    def get_cache_key(self, request: Request, view: Any) -> str:
        return self.cache_format % {"scope": self.scope, "ident": self.get_ident(request)}  # type: ignore[no-any-return]


class TileRateThrottle(AddressRateThrottle):
    """Map tiles per client address (the "tiles" rate, ``CPCC_TILE_RATE``): a tile is public,
    so the address is all there is to count by."""

    scope = "tiles"


class RequestRateThrottle(BaseThrottle):
    """The "user" and the "address" rates (``UserRateThrottle``, ``AddressRateThrottle``),
    counted in one round trip to Redis: a request is refused when either rate refuses it, and
    it counts against each rate that allows it, as DRF counts with several throttles."""

    rates = (UserRateThrottle, AddressRateThrottle)

    def __init__(self) -> None:
        self.throttles = [rate() for rate in self.rates]
        self._refused: list[SharedRateThrottle] = []

    def allow_request(self, request: Request, view: Any) -> bool:
        counted = [t for t in self.throttles if t.rate is not None]
        keys = [t.get_cache_key(request, view) for t in counted]
        shared = [(t, key) for t, key in zip(counted, keys, strict=True) if key is not None]
        answers = None
        if shared and not OUTAGE.skip():
            now = self.throttles[0].timer()
            limits = [(key, t.duration, t.num_requests) for t, key in shared]
            try:
                answers = hit_all(throttle_client(), limits, now=now)
            except redis.RedisError as exc:
                OUTAGE.failed(exc)
        if answers is None:  # each on its own (counted in this process while Redis is out)
            self._refused = [t for t in self.throttles if not t.allow_request(request, view)]
        else:
            self._refused = []
            for (t, key), (allowed, oldest) in zip(shared, answers, strict=True):
                t.key, t.now, t._oldest = key, now, oldest
                if not allowed:
                    self._refused.append(t)
        return not self._refused

    def wait(self) -> float | None:
        waits = [w for w in (t.wait() for t in self._refused) if w is not None]
        return max(waits, default=None)
