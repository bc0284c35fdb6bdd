"""API token authentication with a small cache of recent lookups in each web process.

A script polling the API sends the same token many times a second; looking it up (the token,
its user, the user's customer) costs a query each time. Each process keeps what it looked up
for ``CPCC_TOKEN_CACHE_S`` seconds, keyed by a digest of the token (the token itself is not
kept as a key). A change made through the ORM in this process (a token deleted or rotated, a
user deactivated or deleted, a customer changed) forgets the entries it concerns at once, and
again when its transaction commits; other web processes notice within the TTL, when their
entry expires. A change by ``QuerySet.update()`` (which sends no signal) is noticed within
the TTL everywhere. ``CPCC_TOKEN_CACHE_S=0`` turns the cache off.

Two kinds of token answer to ``Authorization: Token KEY``: the named tokens customers make
(accounts.ApiToken, knox's: keys start with ``cpcc_``, only their digest is stored, and it is
the cache's name for them too) and the one token per user that ``drf_create_token`` makes
(DRF's). A named token's ``last_used`` is written at most once a minute (LAST_USED_EVERY_S),
not at every request.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import pickle
import threading
import time
from collections.abc import Callable
from typing import Any

from django.conf import settings
from django.db.models import Q
from django.utils import timezone
from knox.crypto import hash_token
from knox.settings import knox_settings
from rest_framework import exceptions
from rest_framework.authtoken.models import Token

from accounts.models import ApiToken
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

    def get(self, digest: str) -> tuple[Any, Any] | None:
        with self._lock:
            entry = self._entries.get(digest)
            if entry is None:
                return None
            if entry[3] <= self._clock():
                del self._entries[digest]
                return None
        user, token = pickle.loads(entry[2])
        return user, token

    def put(self, digest: str, user: Any, token: Any, *, ttl_s: float, generation: int) -> None:
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
    entry lasts; a miss reads the token with its user and customer in one query. A named
    token (``cpcc_...``) is looked up by its digest."""

    def authenticate_credentials(self, key: str) -> tuple[Any, Any]:
        if key.startswith(knox_settings.TOKEN_PREFIX):
            return _named_token(key)
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


def _named_token(key: str) -> tuple[Any, ApiToken]:
    """A named token (knox's digest of the key is stored, and names it in the cache)."""
    ttl_s = settings.CPCC_TOKEN_CACHE_S
    digest = hash_token(key)
    if ttl_s > 0:
        cached = TOKENS.get(digest)
        if cached is not None:
            LAST_USED.touch(cached[1])
            return cached  # type: ignore[return-value]
    generation = TOKENS.generation
    token = ApiToken.objects.select_related("user", "user__customer").filter(digest=digest).first()
    if token is None:
        raise exceptions.AuthenticationFailed("Invalid token.")
    if token.expiry is not None and token.expiry <= timezone.now():
        raise exceptions.AuthenticationFailed("Token expired: make a new one.")
    if not token.user.is_active:
        raise exceptions.AuthenticationFailed("User inactive or deleted.")
    if ttl_s > 0:
        TOKENS.put(digest, token.user, token, ttl_s=ttl_s, generation=generation)
    LAST_USED.touch(token)
    return token.user, token


# How often a named token's last_used is written at most: the page says "a minute ago", and a
# script polling the API many times a second costs one write a minute.
LAST_USED_EVERY_S = 60.0


class LastUsed:
    """Writes when named tokens were last used, at most once every LAST_USED_EVERY_S per token:
    this process remembers when it last wrote each one, and the UPDATE itself skips a row that
    another process wrote within that time (so the processes together write about once)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._written: dict[int, float] = {}

    def touch(self, token: ApiToken) -> None:
        now = self._clock()
        with self._lock:
            last = self._written.get(token.pk)
            if last is not None and now - last < LAST_USED_EVERY_S:
                return
            if len(self._written) >= MAX_ENTRIES:
                self._written.clear()
            self._written[token.pk] = now
        moment = timezone.now()
        recently = moment - dt.timedelta(seconds=LAST_USED_EVERY_S)
        if token.last_used is not None and token.last_used > recently:
            return  # as read with the token: written a moment ago
        stale = Q(last_used__isnull=True) | Q(last_used__lte=recently)
        ApiToken.objects.filter(stale, pk=token.pk).update(last_used=moment)

    def clear(self) -> None:
        with self._lock:
            self._written.clear()


LAST_USED = LastUsed()
