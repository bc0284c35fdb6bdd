"""V8 isolates with the VVM-API's prelude installed, made ahead of time on the V8 thread."""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vvm_worker.runtime import v8

logger = logging.getLogger(__name__)

PRELUDE_SOURCE = (Path(__file__).with_name("prelude.js")).read_text(encoding="utf-8")
# How long the platform's own calls into an isolate may take (installing the prelude,
# compiling a program, reading an outcome).
HOST_TIMEOUT_S = 5.0
# How many isolates a pool prepares at once: the owner's maker thread makes isolates one after
# the other, but each one's prelude runs on its own native thread, so a burst of new VVs (a
# worker's start, a bulk submission) waits less for its isolates.
FILL_AT_ONCE = 2


@dataclass
class Prepared:
    """An isolate with the prelude installed (built-ins frozen), not yet given to a VV."""

    isolate: v8.Isolate
    key: str  # the host key, as a JSON string literal


async def prepare() -> Prepared:
    """A new isolate with the prelude; on the V8 thread."""
    isolate = await v8.adopt()
    key = json.dumps(secrets.token_hex(16))

    try:
        await isolate.eval_async(
            f"{PRELUDE_SOURCE}({key});\n//# sourceURL=cpcc-prelude.js", timeout_s=HOST_TIMEOUT_S
        )
    except BaseException:
        isolate.close()
        raise
    return Prepared(isolate, key)


class IsolatePool:
    """Isolates with the prelude installed, made ahead of time on the V8 thread.

    A new isolate and the prelude's freezing of the built-ins cost 5 to 10 ms (measured
    2026-12-02); taking a prepared one makes a VV's first step on a host cost little more
    than its program. It prepares FILL_AT_ONCE isolates at a time.
    ``size`` 0 prepares every isolate when it is needed. The pool's state lives on the V8
    thread (no lock): ``take`` is a call to it.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready: list[Prepared] = []
        self._filling: asyncio.Task[None] | None = None
        # Called once isolates are prepared (a dict: each once however often it asked).
        self._waiters: dict[Callable[[], None], None] = {}
        self._failing = False  # the last preparation ahead failed: nobody waits for the next

    def take(self) -> Prepared:
        return v8.call(self._take)

    def notify_when_ready(self, then: Callable[[], None]) -> bool:
        """Whether work that needs a new isolate should wait for one rather than make it
        itself: True when none is prepared now, and ``then()`` will be called (on the V8
        thread: it must be quick and safe from any thread) once one is, or once preparing
        failed; False when one is prepared (take it), when this pool prepares none ahead, or
        when its last preparation failed (a take makes its own, and meets the error)."""
        if self.size == 0 or self._ready:  # a glance from another thread: len() is atomic
            return False
        return v8.call(lambda: self._wait_for_one(then))

    async def _wait_for_one(self, then: Callable[[], None]) -> bool:
        self._on_this_loop()
        if self._ready or self._failing or self.size == 0:
            return False
        self._waiters[then] = None
        self._fill_soon()
        return True

    def _wake_waiters(self) -> None:
        waiters, self._waiters = self._waiters, {}
        for then in waiters:
            try:
                then()
            except Exception:
                logger.exception("a wait for a prepared isolate could not be ended")

    def fill(self) -> None:
        """Start preparing isolates up to ``size`` now, in the background (a worker that
        expects a burst of new VVs), rather than at the first ``take``."""
        v8.call(self._begin_filling)

    async def _take(self) -> Prepared:
        self._on_this_loop()
        prepared = self._ready.pop() if self._ready else await prepare()
        self._fill_soon()
        return prepared

    async def _begin_filling(self) -> None:
        self._on_this_loop()
        self._fill_soon()

    def _on_this_loop(self) -> None:
        loop = asyncio.get_running_loop()
        if self._loop is not loop:  # first use, or a new owner (after a fork)
            self._loop, self._ready, self._filling, self._waiters = loop, [], None, {}
            self._failing = False

    def _fill_soon(self) -> None:
        """On the owner's loop: prepare isolates up to ``size`` in a background task."""
        if self._filling is None and len(self._ready) < self.size:
            self._filling = asyncio.get_running_loop().create_task(self._fill())

    async def _fill(self) -> None:
        try:
            while (wanted := self.size - len(self._ready)) > 0:
                made = await asyncio.gather(
                    *(prepare() for _ in range(min(wanted, FILL_AT_ONCE))),
                    return_exceptions=True,
                )
                # Those made are kept even when another failed: that one alone is lost.
                self._ready.extend(m for m in made if isinstance(m, Prepared))
                if self._ready:
                    self._wake_waiters()
                for failure in made:
                    if isinstance(failure, BaseException):
                        raise failure
                self._failing = False
        except Exception:
            self._failing = True
            logger.exception("isolates could not be prepared ahead of time")
        finally:
            self._filling = None
            # Whoever still waits takes its turn (and makes its own isolate, or meets the
            # error that stopped this one).
            self._wake_waiters()


# The process's pool; vvm_worker's app sets its size from the settings (CPCC_ISOLATE_POOL).
POOL = IsolatePool(2)
