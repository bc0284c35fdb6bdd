"""The one owner of V8 in this process: a thread that creates, uses and closes every isolate.

V8 is a native engine with process-wide state, and mini-racer does not make every use of it
safe from any thread (issue 20, measured with mini-racer 0.14.1):

- the first isolates made at the same time from several threads crash the process (V8's
  process-wide set-up runs twice: ``Check failed: !IsConfigurablePoolInitialized()``, or a
  segmentation fault), as 16 request threads checking programs did to the web server;
- an isolate closed while the interpreter stops, from another thread than the one using it or
  after its event loop is gone, crashes the process in ``MiniRacer.close`` (every RV worker
  that had run a VV died with a segmentation fault when stopped).

So nothing else in the process touches mini-racer: one thread, started at the first use, runs
an asyncio event loop on which every isolate is made (``mini_racer(event_loop=...)``, so no
isolate has a thread of its own on the Python side) and every isolate is closed. Other threads
reach it through the loop's queue and wait for their answer; the loop serves many isolates at
once (V8 runs each on its own native thread, the loop only hands work to them), so one slow
program does not hold up the others. ``shutdown`` (run at interpreter exit, or by a server that
stops) refuses new work, waits for the work in progress (each call has a timeout), closes every
isolate on the owner thread, and stops it: the process then exits with its own status.

A script is evaluated from the thread that wants its value (``Isolate.eval``): the call goes
straight to the isolate's own native thread, which V8 runs it on, and its value comes back to
the caller alone (mini-racer's queue of the isolate's uncancellable calls), as the owner's
loop would get it, without two more hand-overs between threads (a VV step waited 0.36 ms for a
trivial script through the loop, 0.16 ms this way; issue 23). Its timeout cancels the call:
V8 terminates the script. Such calls count as work in progress for ``shutdown``, and after it
none is accepted. The isolate still has one caller at a time.

Isolates are made inside the process that uses them, never at import time: an isolate made
before ``fork()`` hangs in the child, so a child forgets its parent's owner and makes its own.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import logging
import os
import queue
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

from py_mini_racer import (
    DEFAULT_V8_FLAGS,
    JSEvalException,
    JSOOMException,
    JSParseException,
    JSTimeoutException,
    MiniRacer,
    init_mini_racer,
    mini_racer,
)
from py_mini_racer._context import _UNCANCELABLE_TASK_CALLBACK_ID
from py_mini_racer._exc import JSTerminatedException

__all__ = [
    "Isolate",
    "JSEvalException",
    "JSOOMException",
    "JSParseException",
    "JSTimeoutException",
    "V8Closed",
    "adopt",
    "busy",
    "call",
    "direct",
    "new_isolate",
    "open_isolates",
    "shutdown",
]

logger = logging.getLogger(__name__)

# eval() and Function() inside a VV would run code the platform has not instrumented.
V8_FLAGS = (*DEFAULT_V8_FLAGS, "--disallow-code-generation-from-strings")
# How long a stopping process waits for the V8 work in progress: longer than any one call's
# timeout (a step's CPU quota and its replay allowance).
SHUTDOWN_WAIT_S = 60.0
# How long a script cancelled at its timeout may take to stop (V8's termination is at once).
TERMINATION_WAIT_S = 5.0

T = TypeVar("T")


class V8Closed(RuntimeError):
    """V8 was shut down in this process (it is stopping): no isolate can be made or used."""

    def __init__(self) -> None:
        super().__init__("V8 is shut down in this process (it is stopping)")


class Isolate:
    """One V8 isolate. Its methods may be called from any thread; each runs on the owner's.

    One caller at a time: the isolate runs one script after the other, and a caller that
    shares an isolate between threads must order its calls itself.
    """

    def __init__(self, owner: _Owner, manager: contextlib.AbstractContextManager[MiniRacer]):
        self._owner = owner
        self._manager: contextlib.AbstractContextManager[MiniRacer] | None = manager
        self._mr: MiniRacer | None = None
        self._closing = False  # closed by its user: the owner frees it next
        self._stuck = False  # a script V8 did not stop when cancelled still runs in it

    # --- on the owner's loop ------------------------------------------------------------------

    def _enter(self) -> None:
        assert self._manager is not None
        self._mr = self._manager.__enter__()

    def _exit(self) -> None:
        manager, made = self._manager, self._mr is not None
        self._manager, self._mr = None, None
        if manager is not None and made:
            manager.__exit__(None, None, None)

    def _racer(self) -> MiniRacer:
        if self._mr is None:
            raise V8Closed()
        return self._mr

    async def eval_async(self, code: str, *, timeout_s: float) -> Any:
        """Evaluate ``code``; on the owner's loop only. JSTimeoutException after ``timeout_s``
        (V8 terminates the script)."""
        try:
            return await asyncio.wait_for(self._racer().eval_cancelable(code), timeout_s)
        except TimeoutError:
            raise JSTimeoutException() from None

    # --- from any thread ------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        return self._mr is None or self._closing

    def eval(self, code: str, *, timeout_s: float) -> Any:
        """Evaluate ``code`` and return its value (a primitive); raises mini-racer's
        exceptions (JSParseException, JSEvalException, JSTimeoutException, JSOOMException).
        Not on the owner's thread (its loop uses ``eval_async``)."""
        return self._owner.direct(lambda: self._eval_here(code, timeout_s))

    def _eval_here(self, code: str, timeout_s: float) -> Any:
        if self._stuck:  # its next value would be the stuck script's
            raise JSTimeoutException()
        context = self._racer()._ctx
        assert context is not None
        results = context._non_cancelable_mr_task_results_queue
        code_handle = context._python_to_value_handle(code)
        task = context._dll.mr_eval(context._ctx, code_handle.raw, _UNCANCELABLE_TASK_CALLBACK_ID)
        try:
            value = results.get(timeout=timeout_s)
        except queue.Empty:
            context._dll.mr_cancel_task(context._ctx, task)
            try:  # the terminated script's value, at once (or its own, had it just ended)
                value = results.get(timeout=TERMINATION_WAIT_S)
            except queue.Empty:
                self._stuck = True
                logger.error("a script V8 was told to stop still runs: its isolate is not used")
                raise JSTimeoutException() from None
            try:
                return context._value_handle_to_python(value)
            except JSTerminatedException:
                raise JSTimeoutException() from None
        return context._value_handle_to_python(value)

    def set_hard_memory_limit(self, limit: int) -> None:
        """V8 terminates a script when the heap passes ``limit`` bytes (0: no limit)."""
        self._owner.direct(lambda: self._racer().set_hard_memory_limit(limit))

    def hard_memory_limit_reached(self) -> bool:
        return self._owner.direct(lambda: self._racer().was_hard_memory_limit_reached())

    def heap_stats(self) -> dict[str, Any]:
        return dict(self._owner.call_sync(lambda: self._racer().heap_stats()))

    def close(self) -> None:
        """Free the isolate (idempotent; after shutdown the owner has freed it already). From
        another thread the caller does not wait: the owner frees it after the work queued
        before, and the isolate is not to be used again."""
        if self.closed:
            return
        self._closing = True
        if self._owner.on_owner_thread():
            self._owner.forget(self)
            return
        self._owner.call_soon(lambda: self._owner.forget(self))


class _Maker:
    """The owner's thread that makes isolates, one at a time, for work on the owner's loop.

    A daemon thread of its own (not a concurrent.futures executor, which the interpreter joins
    and closes at exit before the owner's shutdown, while other threads may still need one)."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue[tuple[Callable[[], Any], asyncio.Future[Any]] | None] = (
            queue.SimpleQueue()
        )
        threading.Thread(target=self._work, name="cpcc-v8-maker", daemon=True).start()

    def run(self, work: Callable[[], T]) -> asyncio.Future[T]:
        """``work()`` on the maker's thread; awaited on the owner's loop."""
        future: asyncio.Future[T] = asyncio.get_running_loop().create_future()
        self._jobs.put((work, future))
        return future

    def stop(self) -> None:
        self._jobs.put(None)

    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            work, future = job
            loop = future.get_loop()
            try:
                result = work()
            except BaseException as exc:
                loop.call_soon_threadsafe(_settle, future, None, exc)
            else:
                loop.call_soon_threadsafe(_settle, future, result, None)


def _settle(future: asyncio.Future[Any], result: Any, exc: BaseException | None) -> None:
    if future.cancelled():
        return
    if exc is not None:
        future.set_exception(exc)
    else:
        future.set_result(result)


class _Owner:
    """The owner thread and its event loop, started at the first use."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._closed = False
        self._isolates: set[Isolate] = set()
        self._busy = 0  # calls running on the loop (only the loop's thread changes it)
        self._idle: asyncio.Event | None = None
        self._direct = 0  # calls other threads make themselves (`direct`), under self._lock
        self._depth = threading.local()  # how deep this thread is in such calls
        self._maker: _Maker | None = None
        self._exit_hook = False

    def _start(self) -> asyncio.AbstractEventLoop:
        # Under self._lock.
        if self._closed:
            raise V8Closed()
        if self._loop is not None:
            return self._loop
        loop = asyncio.new_event_loop()
        started = threading.Event()
        failure: list[BaseException] = []
        thread = threading.Thread(
            target=self._serve, args=(loop, started, failure), name="cpcc-v8", daemon=True
        )
        thread.start()
        started.wait()
        if failure:
            raise failure[0]
        self._loop, self._thread = loop, thread
        self._maker = _Maker()
        if not self._exit_hook:
            atexit.register(shutdown)
            self._exit_hook = True
        return loop

    def _serve(
        self,
        loop: asyncio.AbstractEventLoop,
        started: threading.Event,
        failure: list[BaseException],
    ) -> None:
        asyncio.set_event_loop(loop)
        try:
            # V8 reads the time zone once; a VV must not observe the host's (Date is UTC here).
            if os.environ.get("TZ") != "UTC":
                os.environ["TZ"] = "UTC"
                time.tzset()
            init_mini_racer(flags=V8_FLAGS, ignore_duplicate_init=True)
            self._idle = asyncio.Event()
            self._idle.set()
        except BaseException as exc:
            failure.append(exc)
            started.set()
            loop.close()
            return
        started.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    def on_owner_thread(self) -> bool:
        return threading.current_thread() is self._thread

    async def _tracked(self, work: Callable[[], Awaitable[T]]) -> T:
        assert self._idle is not None
        self._busy += 1
        self._idle.clear()
        try:
            return await work()
        finally:
            self._busy -= 1
            if self._busy == 0:
                self._idle.set()

    def call(self, work: Callable[[], Awaitable[T]]) -> T:
        """Run the coroutine ``work()`` on the owner's loop and wait for its result."""
        if self.on_owner_thread():
            raise RuntimeError("a V8 call from the owner's own loop would wait for itself")
        with self._lock:
            # Scheduled under the lock: nothing is accepted after shutdown's own work.
            loop = self._start()
            future = asyncio.run_coroutine_threadsafe(self._tracked(work), loop)
        return future.result()

    def direct(self, work: Callable[[], T]) -> T:
        """Run ``work()``, calls into isolates, on the calling thread, as one piece of work in
        progress that a shutdown waits for: V8Closed once V8 is shut down, unless this thread
        is already inside such work (a step's later calls are made)."""
        depth = getattr(self._depth, "n", 0)
        counted = depth == 0 and not self.on_owner_thread()
        if counted:
            with self._lock:
                self._start()  # V8 is set up (and, once shut down, raises V8Closed)
                self._direct += 1
        self._depth.n = depth + 1
        try:
            return work()
        finally:
            self._depth.n = depth
            if counted:
                with self._lock:
                    self._direct -= 1

    def call_soon(self, work: Callable[[], None]) -> None:
        """Run the quick function ``work()`` on the owner's loop without waiting for it;
        nothing once V8 is shut down (the shutdown did what it would)."""
        with self._lock:
            if self._closed or self._loop is None:
                return
            self._loop.call_soon_threadsafe(work)

    def call_sync(self, work: Callable[[], T]) -> T:
        """Run the quick function ``work()`` on the owner's loop and wait for its result."""
        if self.on_owner_thread():
            return work()

        async def run() -> T:
            return work()

        return self.call(run)

    # --- isolates -----------------------------------------------------------------------------

    def new_isolate(self) -> Isolate:
        """A new isolate (mini-racer's setTimeout installed, nothing else)."""
        return self.call(self.adopt)

    async def adopt(self) -> Isolate:
        """A new isolate, for work running on the owner's loop. It is made by the owner's
        maker thread, one at a time (V8's process-wide set-up must never run twice at once),
        while the loop goes on serving the other isolates: making one takes milliseconds."""
        assert self.on_owner_thread() and self._maker is not None
        loop = asyncio.get_running_loop()
        isolate = Isolate(self, mini_racer(event_loop=loop))
        # Known before it exists: a shutdown that cancels this still closes it.
        self._isolates.add(isolate)
        try:
            await self._maker.run(isolate._enter)
        except BaseException:
            if isolate.closed:  # never made
                self._isolates.discard(isolate)
            raise
        return isolate

    def forget(self, isolate: Isolate) -> None:
        """Close an isolate; on the owner's loop."""
        self._isolates.discard(isolate)
        isolate._exit()

    def open_isolates(self) -> int:
        return len(self._isolates)

    def busy(self) -> int:
        return self._busy + self._direct

    # --- the end ------------------------------------------------------------------------------

    def shutdown(self, *, wait_s: float = SHUTDOWN_WAIT_S) -> None:
        """Refuse new work, let the work in progress end, close every isolate on the owner's
        thread and stop it. Idempotent; a later call to V8 raises V8Closed."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            loop, thread = self._loop, self._thread
            if loop is None or thread is None:
                return
            if self.on_owner_thread():
                raise RuntimeError("V8's owner cannot shut itself down")
            future = asyncio.run_coroutine_threadsafe(self._close_all(wait_s), loop)
        try:
            future.result(wait_s + 10)
        except Exception:
            logger.exception("V8 did not stop cleanly")
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)

    async def _close_all(self, wait_s: float) -> None:
        assert self._idle is not None
        deadline = time.monotonic() + wait_s
        try:
            await asyncio.wait_for(self._idle.wait(), wait_s)
            # (The calls other threads make themselves: none starts now, each has a timeout.)
            while self._direct and time.monotonic() < deadline:
                await asyncio.sleep(0.005)
        except TimeoutError:
            pass
        if self._busy or self._direct:
            # A script still runs: closing its isolate under it would crash the process.
            logger.error("V8 work still running after %.0f s: isolates left open", wait_s)
            return
        # What is left is the owner's own background work (isolates made ahead of time).
        background = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for task in background:
            task.cancel()
        await asyncio.gather(*background, return_exceptions=True)
        if self._maker is not None:  # an isolate still being made is finished first
            await self._maker.run(lambda: None)
            self._maker.stop()
        for isolate in list(self._isolates):
            self.forget(isolate)

    def reset_after_fork(self) -> None:
        """In a forked child: the parent's thread and isolates do not exist here."""
        self._lock = threading.Lock()
        self._loop = None
        self._thread = None
        self._closed = False
        self._isolates = set()
        self._busy = 0
        self._idle = None
        self._direct = 0
        self._depth = threading.local()
        self._maker = None


_OWNER = _Owner()
os.register_at_fork(after_in_child=_OWNER.reset_after_fork)


def new_isolate() -> Isolate:
    """A new V8 isolate owned by this process's V8 thread."""
    return _OWNER.new_isolate()


def direct(work: Callable[[], T]) -> T:
    """Run ``work()``, calls into isolates made here, on this thread as one piece of work
    in progress: a shutdown waits for it, and none starts after the shutdown."""
    return _OWNER.direct(work)


def call(work: Callable[[], Awaitable[T]]) -> T:
    """Run a coroutine on the V8 thread (to use isolates there without a round trip per
    call) and wait for its result."""
    return _OWNER.call(work)


async def adopt() -> Isolate:
    """A new isolate, from work already running on the V8 thread."""
    return await _OWNER.adopt()


def open_isolates() -> int:
    """How many isolates this process has open now."""
    return _OWNER.open_isolates()


def busy() -> int:
    """How many calls to V8 are in progress in this process now."""
    return _OWNER.busy()


def shutdown(*, wait_s: float = SHUTDOWN_WAIT_S) -> None:
    """Close every isolate of this process and stop the V8 thread (see the module's text).
    Runs at interpreter exit; a server calls it when it stops. Idempotent."""
    _OWNER.shutdown(wait_s=wait_s)
