"""An RV worker's plans, made in its planner process and followed on the host thread; made
on the host thread when that process ends."""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Iterator

import pytest

from fleet.geo import Position
from vvm_worker.clock import SystemClock
from vvm_worker.hosts import HostPlanning, RealTimeScheduler
from vvm_worker.planning import PlanTask, TravelTime, make_planner

HERE = Position(47.0, 8.0, 20.0)
TASKS = [
    PlanTask(task_id, Position(47.0 + 0.001 * task_id, 8.0 + 0.002 * (task_id % 3), 20.0), 0.0)
    for task_id in range(1, 10)
]


@pytest.fixture
def scheduler() -> Iterator[RealTimeScheduler]:
    scheduler = RealTimeScheduler(SystemClock())
    thread = threading.Thread(target=scheduler.run, daemon=True)
    thread.start()
    yield scheduler
    scheduler.stop()
    thread.join(5)


@pytest.fixture
def planning(scheduler) -> Iterator[HostPlanning]:
    planning = HostPlanning(scheduler)
    planning.start()
    yield planning
    scheduler.submit(planning.close).result(10)


def _plan_on_the_host_thread(scheduler, planning, *, kill_first: bool = False):  # type: ignore[no-untyped-def]
    """Ask for a plan from the host thread (the planner process killed first, in the same
    piece of work, if asked): the route it comes back with, and who planned it."""
    planner = make_planner("latency", travel_time=TravelTime(10.0))
    came_back = threading.Event()
    routes: list[list[PlanTask]] = []

    def then(route: list[PlanTask]) -> None:
        routes.append(route)
        came_back.set()

    def ask() -> None:
        if kill_first:
            assert planning.process is not None and planning.process.pid is not None
            os.kill(planning.process.pid, signal.SIGKILL)
        planning.plan("RV-1", planner, HERE, TASKS, 5.0, then)

    scheduler.submit(ask).result(10)
    assert came_back.wait(20)
    return routes[0], planner


def _expected() -> list[int]:
    return [
        t.id for t in make_planner("latency", travel_time=TravelTime(10.0)).plan(HERE, TASKS, 5.0)
    ]


def test_a_plan_made_in_the_planner_process_comes_back_to_the_host_thread(
    scheduler, planning
) -> None:
    pid = planning.process.pid
    route, planner = _plan_on_the_host_thread(scheduler, planning)
    assert [task.id for task in route] == _expected()
    assert route[0] is TASKS[route[0].id - 1]  # the tasks it was asked with, in its order
    assert planner.state() == {"route": _expected()}  # the state after the plan, here too
    assert pid is not None and pid != os.getpid()


def test_when_the_process_ends_soon_after_its_start_the_host_thread_plans(
    scheduler, planning, caplog
) -> None:
    with caplog.at_level(logging.ERROR, logger="cpcc.hosts"):
        route, _ = _plan_on_the_host_thread(scheduler, planning, kill_first=True)
    assert [task.id for task in route] == _expected()
    assert planning.process is None
    assert "the vehicles are planned on the host thread from now on" in caplog.text
    again, _ = _plan_on_the_host_thread(scheduler, planning)
    assert [task.id for task in again] == _expected()


def test_a_process_that_ended_after_a_while_is_started_again(scheduler, planning) -> None:
    planning.RESTART_AFTER_S = 0.0
    first = planning.process.pid
    route, _ = _plan_on_the_host_thread(scheduler, planning, kill_first=True)
    assert [task.id for task in route] == _expected()
    assert planning.process is not None and planning.process.pid not in (None, first)
    again, _ = _plan_on_the_host_thread(scheduler, planning)
    assert [task.id for task in again] == _expected()


def test_closing_ends_the_planner_process(scheduler, planning) -> None:
    process = planning.process
    assert process is not None
    scheduler.submit(planning.close).result(10)
    deadline = time.monotonic() + 20
    while process.exitcode is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert process.exitcode == 0
