"""What the runtime works out from a program's text (its syntax check, its instrumented form),
remembered in each process by a digest of the text and bounded by the bytes it holds.

``functools.lru_cache`` keyed by the text itself kept every program it saw: 200 different
programs of a million characters sent to the dry-run endpoint took a web process from 214 MB
to 1.4 GB, for good. Here a key is 32 bytes whatever the program, and what is kept is bounded
by its size (cachetools' ``LRUCache`` with ``getsizeof``), not by a number of entries.
"""

from __future__ import annotations

import contextlib
import hashlib
import threading
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

import cachetools

V = TypeVar("V")
_MISSING = object()

# What an entry costs besides its value: the digest, the key tuple, the cache's own links.
ENTRY_BYTES = 256


def text_digest(text: str) -> bytes:
    """SHA-256 of the text as UTF-8 (a lone surrogate, which JavaScript allows, kept)."""
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).digest()


class TextMemo(Generic[V]):
    """``compute(text, *extra)`` remembered by the text's digest and ``extra``, least recently
    used first out once the values (as ``size_of`` measures them) pass ``max_bytes``. A value
    larger than that is computed each time. An exception is not remembered. Thread-safe; two
    threads may compute the same text at once (both get the same answer)."""

    def __init__(
        self, compute: Callable[..., V], *, max_bytes: int, size_of: Callable[[V], int]
    ) -> None:
        self._compute = compute
        self.max_bytes = max_bytes
        self._cache: cachetools.LRUCache[tuple[bytes, tuple[Hashable, ...]], V] = (
            cachetools.LRUCache(maxsize=max_bytes, getsizeof=lambda v: size_of(v) + ENTRY_BYTES)
        )
        self._lock = threading.Lock()

    def __call__(self, text: str, *extra: Hashable) -> V:
        key = (text_digest(text), extra)
        with self._lock:
            found = self._cache.get(key, _MISSING)
        if found is not _MISSING:
            return found  # type: ignore[return-value]
        value = self._compute(text, *extra)
        with self._lock, contextlib.suppress(ValueError):  # larger than the cache: not kept
            self._cache[key] = value
        return value

    @property
    def held_bytes(self) -> int:
        """The bytes the remembered values count for now."""
        with self._lock:
            return int(self._cache.currsize)

    def __len__(self) -> int:
        with self._lock:
            return len(self._cache)

    def clear(self) -> None:
        with self._lock:
            self._cache.clear()
