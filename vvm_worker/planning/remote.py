"""Plans made in a process of its own, beside an RV worker's host thread.

A plan is Python (a millisecond or more for twenty open tasks, a fifth of what a task costs
the host thread): made in the worker's own process it holds the interpreter lock, which a
thread of the same process cannot share, and the worker serves nothing meanwhile. The
planner process makes the plans on the machine's other core while the host thread goes on
with the other vehicles, and the vehicle follows its plan when it is back.

`PlannerProcess` starts the process (spawned: a fresh interpreter, nothing of the worker's
threads, V8 or database connections in it), which keeps one planner per vehicle: sent once
(`send_planner`), with its costs and the cache of costs it builds; each request (`ask`)
carries the vehicle's planner state, so that the process plans from the state the worker
knows (after a restore, say), and each answer carries the state after the plan. The process
ends when asked (`stop`) or when its pipe closes (its worker ended) and ignores SIGINT (a Ctrl-C in a
terminal goes to the whole group: the worker stops it when it has stopped itself); SIGTERM
ends it (multiprocessing ends a worker's daemon processes with it, and a service manager
that stops the worker's whole group, as systemd does, stops it too).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from fleet.geo import Position

from .base import Planner, PlanTask


@dataclass(frozen=True)
class PlanAnswer:
    """The answer to request ``request``: the planned task ids in order and the planner's
    state after the plan, or ``error`` (what the planner raised) and neither."""

    request: int
    task_ids: list[int] | None
    state: Any = None
    error: str | None = None


class PlannerProcess:
    """The planner process of one worker and the worker's end of its pipe (used by one thread
    to send, `answers` by one other thread to receive)."""

    def __init__(self) -> None:
        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._process = context.Process(
            target=_serve, args=(child,), name="cpcc-planner", daemon=True
        )
        self._process.start()
        child.close()

    @property
    def pid(self) -> int | None:
        return self._process.pid

    @property
    def exitcode(self) -> int | None:
        """The process's exit status once it has ended (None while it runs)."""
        return self._process.exitcode

    def send_planner(self, key: str, planner: Planner) -> None:
        """Plan ``key``'s requests with ``planner`` (a copy of it) from now on."""
        self._conn.send(("planner", key, planner))

    def ask(
        self,
        request: int,
        key: str,
        state: Any,
        current: Position,
        tasks: Sequence[PlanTask],
        now_s: float,
    ) -> None:
        """Ask for ``key``'s plan (its planner's ``plan``) from ``state``; the answer comes
        through `answers`. Raises OSError (BrokenPipeError) when the process has ended."""
        rows = [  # plain tuples: a twentieth of the dataclasses' pickling time
            (t.id, t.position.lat, t.position.lng, t.position.alt, t.requested_s, t.group, t.weight)
            for t in tasks
        ]
        here = (current.lat, current.lng, current.alt)
        self._conn.send(("plan", request, key, state, here, rows, now_s))

    def answers(self) -> Iterator[PlanAnswer]:
        """The answers as they come, until the process ends (then the worker's end of the
        pipe is closed: by the thread that reads, never under a read of another thread)."""
        try:
            while True:
                yield self._conn.recv()
        except (EOFError, OSError):
            self._conn.close()

    def stop(self) -> None:
        """Ask the process to end (without waiting): `answers` ends when it has."""
        with contextlib.suppress(OSError):  # (ended already)
            self._conn.send(None)

    def join(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for the process to end (see `exitcode`)."""
        self._process.join(timeout_s)

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the process and wait for it (killed if it does not end in time), for a caller
        that does not read `answers`."""
        self.stop()
        self._process.join(timeout_s)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        self._conn.close()


def _serve(conn: Connection) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    planners: dict[str, Planner] = {}
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:  # stop
            return
        if message[0] == "planner":
            _, key, planner = message
            planners[key] = planner
            continue
        _, request, key, state, here, rows, now_s = message
        try:
            current = Position(*here)
            tasks = [
                PlanTask(task_id, Position(lat, lng, alt), requested_s, group, weight)
                for task_id, lat, lng, alt, requested_s, group, weight in rows
            ]
            planner = planners[key]
            if planner.state() != state:
                planner.restore(state)
            route = planner.plan(current, tasks, now_s)
            answer = PlanAnswer(request, [task.id for task in route], planner.state())
        except Exception as exc:  # the worker logs it, with the vehicle's name
            answer = PlanAnswer(request, None, error=f"{type(exc).__name__}: {exc}")
        try:
            conn.send(answer)
        except OSError:
            return
