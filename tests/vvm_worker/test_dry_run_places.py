"""Who may start a dry run (vvm_worker/dry_run_places.py, no Django): one per customer, places
handed out in the order they were asked for, and a CPU budget per customer over a window."""

from __future__ import annotations

import threading

import pytest

from vvm_worker.dry_run_places import DryRunPlaces, Refused

ROOMY = {"cpu_budget_s": 100.0, "window_s": 600.0}


def waiting_for_a_place(places: DryRunPlaces, customer: str, got: list[str]) -> threading.Thread:
    def take() -> None:
        places.take(customer, wait_s=30.0, **ROOMY)
        got.append(customer)

    thread = threading.Thread(target=take, daemon=True)
    thread.start()
    return thread


def queued(places: DryRunPlaces, n: int) -> None:
    with places._changed:  # what the threads wait on: no sleeping to guess when they wait
        assert places._changed.wait_for(lambda: len(places._queue) == n, timeout=10)


def test_waiting_customers_get_the_place_in_the_order_they_asked() -> None:
    places = DryRunPlaces(1)
    places.take("A", wait_s=0, **ROOMY)
    got: list[str] = []
    b = waiting_for_a_place(places, "B", got)
    queued(places, 1)
    c = waiting_for_a_place(places, "C", got)
    queued(places, 2)

    places.give_back("A", cpu_s=1.0)
    b.join(10)
    assert got == ["B"] and c.is_alive(), "C came after B"
    places.give_back("B", cpu_s=1.0)
    c.join(10)
    assert got == ["B", "C"]


def test_a_customer_has_one_dry_run_at_a_time_and_others_are_not_held_back() -> None:
    places = DryRunPlaces(2)
    places.take("A", wait_s=0, **ROOMY)
    with pytest.raises(Refused, match="A dry run of yours is running already") as refused:
        places.take("A", wait_s=0, **ROOMY)
    assert refused.value.retry_after_s == 5.0
    places.take("B", wait_s=0, **ROOMY)  # the second place: B is not refused because of A
    with pytest.raises(Refused, match="2 dry runs are running on this server already"):
        places.take("C", wait_s=0.05, **ROOMY)
    places.give_back("A", cpu_s=0.5)
    places.take("C", wait_s=0, **ROOMY)
    with pytest.raises(Refused, match="2 dry runs are running"):
        places.take("A", wait_s=0, **ROOMY)


def test_one_that_gives_up_waiting_leaves_the_line_to_the_next() -> None:
    places = DryRunPlaces(1)
    places.take("A", wait_s=0, **ROOMY)
    with pytest.raises(Refused, match="1 dry runs are running"):
        places.take("B", wait_s=0.05, **ROOMY)
    got: list[str] = []
    c = waiting_for_a_place(places, "C", got)
    queued(places, 1)
    places.give_back("A", cpu_s=1.0)
    c.join(10)
    assert got == ["C"]
    places.give_back("C", cpu_s=1.0)
    places.take("B", wait_s=0, **ROOMY)  # B may ask again: it waits in no line any more


def test_a_customer_over_its_cpu_budget_is_told_when_it_may_go_on() -> None:
    now = [1000.0]
    places = DryRunPlaces(2, clock=lambda: now[0])
    budget = {"cpu_budget_s": 100.0, "window_s": 600.0}
    for cpu_s in (40.0, 70.0):
        places.take("A", wait_s=0, **budget)
        places.give_back("A", cpu_s=cpu_s)
        now[0] += 100.0
    # 110 s within the window: until the first run (at 1000 s, 40 s) leaves it, at 1600 s.
    with pytest.raises(Refused) as refused:
        places.take("A", wait_s=0, **budget)
    assert str(refused.value) == (
        "Your dry runs used 110 s of CPU in the last 600 s, 100 s allowed: the next can start "
        "in 400 s."
    )
    assert refused.value.retry_after_s == pytest.approx(400.0)
    places.take("B", wait_s=0, **budget)  # the budget is A's own
    now[0] = 1600.0
    places.take("A", wait_s=0, **budget)
