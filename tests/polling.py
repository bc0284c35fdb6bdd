"""Waiting in tests: poll a condition until it holds, with a deadline (never a fixed sleep).
The one helper every test waits with, in a thread or in a coroutine."""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Callable
from typing import Any


def wait_until(
    condition: Callable[[], Any],
    *,
    timeout: float = 60.0,
    what: str = "the condition",
    details: Callable[[], str] | None = None,
    interval: float = 0.05,
) -> Any:
    """Poll ``condition`` every ``interval`` seconds until it returns something truthy, and
    return that; fail after ``timeout`` wall seconds saying ``what`` it waited for (and
    ``details()``, e.g. the workers' logs or a ground station's output at that moment)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(_timed_out(timeout, what, details))
        time.sleep(interval)


async def wait_until_async(
    condition: Callable[[], Any],
    *,
    timeout: float = 60.0,
    what: str = "the condition",
    details: Callable[[], str] | None = None,
    interval: float = 0.01,
) -> Any:
    """``wait_until`` in a coroutine: the event loop runs on while it waits. ``condition``
    may be a coroutine function (a client's query)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if inspect.isawaitable(value):
            value = await value
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(_timed_out(timeout, what, details))
        await asyncio.sleep(interval)


def _timed_out(timeout: float, what: str, details: Callable[[], str] | None) -> str:
    more = f"\n{details()}" if details is not None else ""
    return f"timed out after {timeout:g} s waiting for {what}{more}"
