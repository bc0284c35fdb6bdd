"""The planner process: plans as the planner in this process would, from the state it is
told, and answers a planner's failure with what it raised."""

from __future__ import annotations

import os
import random
import signal
from collections.abc import Iterator

import pytest

from fleet.geo import Position
from vvm_worker.planning import PlanTask, TravelTime, make_planner
from vvm_worker.planning.remote import PlannerProcess

HERE = Position(47.0, 8.0, 20.0)


@pytest.fixture
def process() -> Iterator[PlannerProcess]:
    process = PlannerProcess()
    yield process
    process.close()


def _tasks(count: int, seed: int = 1) -> list[PlanTask]:
    rnd = random.Random(seed)
    return [
        PlanTask(
            task_id,
            Position(47.0 + rnd.random() * 0.01, 8.0 + rnd.random() * 0.01, 20.0),
            float(task_id),
            group="batch" if task_id in (3, 4) else None,
            weight=2.0 if task_id == 5 else 1.0,
        )
        for task_id in range(1, count + 1)
    ]


def test_plans_are_the_planners_here_from_the_state_each_request_carries(process) -> None:
    here = make_planner("latency", travel_time=TravelTime(10.0))
    process.send_planner("RV-1", make_planner("latency", travel_time=TravelTime(10.0)))
    answers = process.answers()
    tasks = _tasks(20)
    for request, open_tasks in enumerate([tasks, tasks[3:], tasks[3:] + _tasks(2, seed=7)]):
        process.ask(request, "RV-1", here.state(), HERE, open_tasks, 30.0)
        answer = next(answers)
        expected = [task.id for task in here.plan(HERE, open_tasks, 30.0)]
        assert (answer.request, answer.task_ids, answer.error) == (request, expected, None)
        assert answer.state == here.state()
    # A state the process did not plan from (a vehicle's restored plan) is where it starts.
    here.restore({"route": [7, 6, 5]})
    process.ask(9, "RV-1", here.state(), HERE, tasks[4:9], 30.0)
    assert next(answers).task_ids == [task.id for task in here.plan(HERE, tasks[4:9], 30.0)]


def test_a_planner_that_raises_is_answered_with_what_it_raised(process) -> None:
    process.send_planner("RV-1", make_planner("latency"))
    process.ask(1, "RV-1", {"route": "not a list"}, HERE, _tasks(3), 1.0)
    process.ask(2, "RV-2", {}, HERE, _tasks(3), 1.0)  # no planner sent for it
    answers = process.answers()
    first, second = next(answers), next(answers)
    assert (first.request, first.task_ids) == (1, None)
    assert "ValueError" in first.error and "'route' must be a list" in first.error
    assert (second.request, second.task_ids, second.error) == (2, None, "KeyError: 'RV-2'")


def test_the_process_outlives_a_ctrl_c_to_its_group_and_ends_with_its_pipe(process) -> None:
    process.send_planner("RV-1", make_planner("latency"))
    process.ask(1, "RV-1", {}, HERE, _tasks(2), 1.0)
    answers = process.answers()
    assert next(answers).task_ids is not None  # (the process is up: its handler is set)
    assert process.pid is not None
    os.kill(process.pid, signal.SIGINT)
    process.ask(2, "RV-1", {}, HERE, _tasks(2), 1.0)
    assert next(answers).request == 2
    process.close()
    assert process.exitcode == 0
