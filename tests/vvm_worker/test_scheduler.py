"""The host thread's scheduler: work from other threads, timers, and work that must wait."""

from __future__ import annotations

import concurrent.futures
import threading
from collections.abc import Iterator

import pytest

from vvm_worker.clock import SystemClock
from vvm_worker.hosts import HostStopped, NotYet, RealTimeScheduler


@pytest.fixture
def scheduler() -> Iterator[RealTimeScheduler]:
    scheduler = RealTimeScheduler(SystemClock())
    yield scheduler
    scheduler.stop()


def _start(scheduler: RealTimeScheduler) -> threading.Thread:
    thread = threading.Thread(target=scheduler.run, daemon=True)
    thread.start()
    return thread


def _work_that_sends_work(
    scheduler: RealTimeScheduler, order: list[str], name: str
) -> tuple[concurrent.futures.Future[None], list[concurrent.futures.Future[None]]]:
    """Submit work (a VV's start) that notes ``name`` and sends the host a piece of work of
    its own, which notes "sent by <name>": the work's future, and the list that gets the
    sent piece's future."""
    sent: list[concurrent.futures.Future[None]] = []

    def work() -> None:
        order.append(name)
        sent.append(scheduler.submit(lambda: order.append(f"sent by {name}")))

    return scheduler.submit(work), sent


def test_work_that_cannot_be_done_yet_waits_parked_while_other_work_goes_on(scheduler) -> None:
    isolates = 0
    done: list[str] = []

    def start(name: str):  # type: ignore[no-untyped-def]
        def work() -> str:
            nonlocal isolates
            if not isolates:
                raise NotYet(f"{name}: no isolate")
            isolates -= 1
            done.append(name)
            return name

        return work

    _start(scheduler)
    first, second = scheduler.submit(start("first")), scheduler.submit(start("second"))
    assert scheduler.submit(lambda: "other work").result(5) == "other work"
    assert not first.done() and not second.done() and done == []
    isolates = 1
    scheduler.resume_parked()
    assert first.result(5) == "first"
    # The second still waits, behind nothing now, and it is not lost.
    assert scheduler.submit(lambda: done.copy()).result(5) == ["first"]
    assert not second.done()
    isolates = 1
    scheduler.resume_parked()
    assert second.result(5) == "second" and done == ["first", "second"]


def test_parked_work_resumes_in_the_order_it_came(scheduler) -> None:
    ready = False
    done: list[int] = []

    def work(n: int):  # type: ignore[no-untyped-def]
        def run() -> None:
            if not ready:
                raise NotYet("wait")
            done.append(n)

        return run

    _start(scheduler)
    futures = [scheduler.submit(work(n)) for n in range(5)]
    scheduler.submit(lambda: None).result(5)
    ready = True
    scheduler.resume_parked()
    for future in futures:
        future.result(5)
    assert done == [0, 1, 2, 3, 4]


def test_work_sent_by_work_waits_for_a_due_timer() -> None:
    """A chain of work (a VV's start sends its next piece) must not hold up the vehicles'
    timers: what the work sends to the host runs after the next due timer."""
    scheduler = RealTimeScheduler(SystemClock())
    order: list[str] = []
    scheduler.call_at(0.0, lambda: order.append("timer"))  # due at once
    started, sent = _work_that_sends_work(scheduler, order, "first")
    _start(scheduler)
    try:
        started.result(5)
        sent[0].result(5)
        assert order == ["first", "timer", "sent by first"]
    finally:
        scheduler.stop()


def test_parked_work_is_not_done_when_the_host_stops_and_its_waiter_learns_it_at_once() -> None:
    scheduler = RealTimeScheduler(SystemClock())
    thread = _start(scheduler)

    def never() -> None:
        raise NotYet("no isolate")

    parked = scheduler.submit(never)
    scheduler.submit(lambda: None).result(5)
    scheduler.stop()
    thread.join(5)
    with pytest.raises(HostStopped):
        parked.result(5)


def test_every_vehicles_due_timer_runs_between_two_looks_at_the_inbox() -> None:
    """A burst of work (new VVs) must not hold up the VVs aboard: between two looks at the
    inbox every timer due runs, one per vehicle, not one for all of them; a timer that a
    timer sets for now (an instant flight's next arrival) waits for the next look, so that
    the work that came in meanwhile is not held up either."""
    scheduler = RealTimeScheduler(SystemClock())
    order: list[str] = []

    def arrival(rv: str, again: bool):  # type: ignore[no-untyped-def]
        def run() -> None:
            order.append(rv)
            if again:  # the vehicle flies on to its next point at once
                scheduler.call_at(0.0, arrival(f"{rv} again", False))

        return run

    for rv in ("rv1", "rv2", "rv3"):
        scheduler.call_at(0.0, arrival(rv, True))  # due at once
    started, sent = _work_that_sends_work(scheduler, order, "start")
    _start(scheduler)
    try:
        started.result(5)
        sent[0].result(5)
        scheduler.submit(lambda: None).result(5)
        assert order[:6] == ["start", "rv1", "rv2", "rv3", "sent by start", "rv1 again"]
    finally:
        scheduler.stop()
