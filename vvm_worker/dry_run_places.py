"""Who may start a dry run in this process now: a few places, one per customer, first come
first served, and a budget of CPU seconds per customer over a sliding window.

Without it one customer could hold every place (two dry runs of 28 s, and the next customer
was refused). No Django here: ``vvm_worker.services.dry_run`` keeps one ``DryRunPlaces`` per
process and tells it what each dry run cost.
"""

from __future__ import annotations

import collections
import itertools
import threading
import time
from collections.abc import Callable, Hashable

# How long to come back after when every place stays taken.
BUSY_RETRY_S = 5.0


class Refused(Exception):
    """A dry run that may not start now: why, for the customer, and when to try again."""

    def __init__(self, reason: str, retry_after_s: float) -> None:
        super().__init__(reason)
        self.retry_after_s = retry_after_s


class DryRunPlaces:
    """``places`` dry runs at once, at most one of them (running or waiting) per customer;
    waiting requests get a place in the order they came. A customer whose dry runs used their
    CPU budget within the window waits until the oldest of them leave it. Thread-safe."""

    def __init__(self, places: int, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.places = places
        self._clock = clock
        self._changed = threading.Condition()
        self._running = 0
        self._queue: collections.deque[int] = collections.deque()
        self._tickets = itertools.count()
        self._customers: set[Hashable] = set()  # with a dry run running or waiting
        self._spent: dict[Hashable, collections.deque[tuple[float, float]]] = {}

    def take(
        self, customer: Hashable, *, wait_s: float, cpu_budget_s: float, window_s: float
    ) -> None:
        """A place for the customer's dry run, waiting up to ``wait_s`` for one; the caller
        gives it back with ``give_back``. Raises Refused."""
        with self._changed:
            if customer in self._customers:
                raise Refused(
                    "A dry run of yours is running already: one at a time. Try again when it "
                    "has answered.",
                    BUSY_RETRY_S,
                )
            now = self._clock()
            spent = self._spent_within(customer, now, window_s)
            if spent >= cpu_budget_s:
                again = self._budget_back_in(customer, now, window_s, cpu_budget_s)
                raise Refused(
                    f"Your dry runs used {spent:.0f} s of CPU in the last {window_s:g} s, "
                    f"{cpu_budget_s:g} s allowed: the next can start in {again:.0f} s.",
                    again,
                )
            ticket = next(self._tickets)
            self._queue.append(ticket)
            self._customers.add(customer)
            self._changed.notify_all()  # (one who watches the line sees it grow)
            deadline = now + wait_s
            while self._queue[0] != ticket or self._running >= self.places:
                left = deadline - self._clock()
                if left <= 0 or not self._changed.wait(left):
                    if self._queue[0] == ticket and self._running < self.places:
                        break  # freed just as the wait ended
                    self._queue.remove(ticket)
                    self._customers.discard(customer)
                    self._changed.notify_all()  # the next in line may be first now
                    raise Refused(
                        f"{self.places} dry runs are running on this server already; try "
                        "again in a few seconds.",
                        BUSY_RETRY_S,
                    )
            self._queue.popleft()
            self._running += 1
            self._changed.notify_all()  # the next in line may take another free place

    def give_back(self, customer: Hashable, *, cpu_s: float) -> None:
        """The customer's dry run ended, having cost ``cpu_s`` seconds of CPU."""
        with self._changed:
            self._running -= 1
            self._customers.discard(customer)
            self._spent.setdefault(customer, collections.deque()).append(
                (self._clock(), max(0.0, cpu_s))
            )
            self._changed.notify_all()

    def _spent_within(self, customer: Hashable, now: float, window_s: float) -> float:
        spent = self._spent.get(customer)
        if spent is None:
            return 0.0
        while spent and spent[0][0] <= now - window_s:
            spent.popleft()
        if not spent:
            del self._spent[customer]
            return 0.0
        return sum(cpu for _, cpu in spent)

    def _budget_back_in(
        self, customer: Hashable, now: float, window_s: float, cpu_budget_s: float
    ) -> float:
        """Seconds until what the customer spent within the window is under the budget."""
        left = sum(cpu for _, cpu in self._spent[customer])
        for at, cpu in self._spent[customer]:
            left -= cpu
            if left < cpu_budget_s:
                return max(1.0, at + window_s - now)
        return 1.0
