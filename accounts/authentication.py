"""API token authentication with a small cache of recent lookups in each web process.

A script polling the API sends the same token many times a second; looking it up (the token,
its user, the user's customer) costs a query each time. Each process keeps what it looked up
for ``CPCC_TOKEN_CACHE_S`` seconds, keyed by a digest of the token (the token itself is not
kept as a key). A change made through the ORM in this process (a token deleted or rotated, a
user deactivated or deleted, a customer changed) forgets the entries it concerns at once, and
again when its transaction commits; other web processes notice within the TTL, when their
entry expires. A change by ``QuerySet.update()`` (which sends no signal) is noticed within
the TTL everywhere. ``CPCC_TOKEN_CACHE_S=0`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import pickle
import threading
import time
from collections.abc import Callable
from typing import Any

from django.conf import settings
from rest_framework import exceptions
from rest_framework.authtoken.models import Token

from cpcc_site.api import AuditedTokenAuthentication

# Tokens remembered per process at most (a web process serves a few hundred users at once).
MAX_ENTRIES = 4096


def token_digest(key: str) -> str:
    """The cache's name for a token."""
    return hashlib.sha256(key.encode()).hexdigest()


class TokenCache:
    """Recent token lookups of this process: digest -> (user id, customer id, pickled
    (user, token), expiry). Thread-safe (ASGI runs requests in threads). Entries are pickled so
    that no two requests share a user object.

    A lookup that was under way while something was forgotten is not kept (``put`` with the
    ``generation`` seen before the lookup): it may have read what was just revoked.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._entries: dict[str, tuple[int, int | None, bytes, float]] = {}
        self._generation = 0

    @property
    def generation(self) -> int:
        """How many times something was forgotten: a lookup notes it before it reads."""
        return self._generation

    def get(self, digest: str) -> tuple[Any, Token] | None:
        with self._lock:
            entry = self._entries.get(digest)
            if entry is None:
                return None
            if entry[3] <= self._clock():
                del self._entries[digest]
                return None
        user, token = pickle.loads(entry[2])
        return user, token

    def put(self, digest: str, user: Any, token: Token, *, ttl_s: float, generation: int) -> None:
        data = pickle.dumps((user, token), protocol=pickle.HIGHEST_PROTOCOL)
        with self._lock:
            if generation != self._generation:
                return
            self._entries.pop(digest, None)
            if len(self._entries) >= MAX_ENTRIES:  # the oldest goes first
                del self._entries[next(iter(self._entries))]
            expiry = self._clock() + ttl_s
            self._entries[digest] = (user.pk, user.customer_id, data, expiry)

    def forget(
        self,
        *,
        digest: str | None = None,
        user_id: int | None = None,
        customer_id: int | None = None,
    ) -> None:
        """Drop the entry of a token, and every entry of a user or of a customer's users."""
        with self._lock:
            self._generation += 1
            gone = [
                name
                for name, (user, customer, _, _) in self._entries.items()
                if name == digest
                or (user_id is not None and user == user_id)
                or (customer_id is not None and customer == customer_id)
            ]
            for name in gone:
                del self._entries[name]

    def clear(self) -> None:
        with self._lock:
            self._generation += 1
            self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)


TOKENS = TokenCache()


class CachedTokenAuthentication(AuditedTokenAuthentication):
    """DRF's token authentication (audited), answered from this process's TokenCache while the
    entry lasts; a miss reads the token with its user and customer in one query."""

    def authenticate_credentials(self, key: str) -> tuple[Any, Token]:
        ttl_s = settings.CPCC_TOKEN_CACHE_S
        digest = token_digest(key)
        if ttl_s > 0:
            cached = TOKENS.get(digest)
            if cached is not None:
                return cached
        generation = TOKENS.generation
        try:
            token = Token.objects.select_related("user", "user__customer").get(key=key)
        except Token.DoesNotExist:
            raise exceptions.AuthenticationFailed("Invalid token.") from None
        if not token.user.is_active:
            raise exceptions.AuthenticationFailed("User inactive or deleted.")
        if ttl_s > 0:
            TOKENS.put(digest, token.user, token, ttl_s=ttl_s, generation=generation)
        return token.user, token
