"""The control loop on its own (no Django): when it plans."""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Sequence
from typing import Any

import pytest
from shapely.geometry import Polygon

from fleet.airspace import Airspace, ExclusionZone
from fleet.driving import LINK_LOST
from fleet.geo import Position, offset
from fleet.mavlink.errors import LinkLost, PreArmFailed
from fleet.mavlink.wire import mavlink
from fleet.simulation import SimVehicle, VehicleSpec
from vvm_worker.control import (
    ACTIVE,
    NO_WAY,
    OFFLINE,
    Area,
    ControlLoop,
    LoopConfig,
    LoopTask,
    VehicleState,
)
from vvm_worker.planning import PlanTask, TravelTime, make_planner

DEPOT = Position(47.0, 8.0, 0.0)


class Store:
    def __init__(self) -> None:
        self.open: dict[int, LoopTask] = {}
        self.served: list[tuple[int, float]] = []

    def open_tasks(self) -> Sequence[LoopTask]:
        return sorted(self.open.values(), key=lambda t: (t.requested_s, t.id))

    def status(self) -> str:
        return ACTIVE

    def set_status(self, status: str, *, expected: str | None = None, reason: str = "") -> None:
        raise AssertionError("no battery here")

    def take_command(self) -> None:
        return None  # no operator here

    def complete(self, task: LoopTask, readings: list[dict[str, Any]], now_s: float) -> None:
        del self.open[task.id]
        self.served.append((task.id, now_s))

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        pass

    def area(self) -> Area:
        ring = [
            offset(DEPOT, north_m=n, east_m=e) for n, e in ((-500, -500), (500, -500), (500, 500))
        ]
        return Area(Polygon([(p.lng, p.lat) for p in ring]), 0.0, 60.0)

    def aboard(self) -> list[dict[str, Any]]:
        return []


class Clock:
    """Discrete events, with the loop's timers run only when the test says."""

    def __init__(self) -> None:
        self.now = 0.0
        self.timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()

    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self.timers, (t_s, next(self._seq), fn))

    def run_due(self) -> None:
        while self.timers and self.timers[0][0] <= self.now:
            heapq.heappop(self.timers)[2]()


class CountingPlanner:
    def __init__(self) -> None:
        self.inner = make_planner("latency", travel_time=TravelTime(10.0, 3.0))
        self.plans = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def plan(self, here: Position, tasks: list[PlanTask], now: float) -> list[PlanTask]:
        self.plans += 1
        return self.inner.plan(here, tasks, now)


def _loop(*, defers: bool) -> tuple[ControlLoop, Store, Clock, CountingPlanner]:
    store, clock, planner = Store(), Clock(), CountingPlanner()
    loop = ControlLoop(
        name="RV",
        driver=SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT),
        planner=planner,  # type: ignore[arg-type]
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        config=LoopConfig(wake_defers_to_arrival=defers),
    )
    return loop, store, clock, planner


def _task(task_id: int, east_m: float) -> LoopTask:
    return LoopTask(task_id, offset(DEPOT, north_m=0.0, east_m=east_m, up_m=10.0), 1.0, 0.0)


def test_a_wake_up_at_the_target_with_its_arrival_due_leaves_the_plan_to_the_arrival() -> None:
    loop, store, clock, planner = _loop(defers=True)
    store.open[1] = _task(1, 100.0)
    loop.wake()
    assert (loop.target, planner.plans) == (1, 1)
    clock.now = clock.timers[0][0] + 1.0  # there, the arrival not taken up yet
    store.open[2] = _task(2, 200.0)
    loop.wake()
    assert planner.plans == 1  # no plan: the arrival plans with the new task
    clock.run_due()
    assert [task for task, _ in store.served] == [1]
    assert (loop.target, planner.plans) == (2, 2)
    clock.now = clock.timers[0][0]
    clock.run_due()
    assert [task for task, _ in store.served] == [1, 2]


def test_a_wake_up_in_flight_plans_at_once() -> None:
    loop, store, clock, planner = _loop(defers=True)
    store.open[1] = _task(1, 300.0)
    loop.wake()
    clock.now = clock.timers[0][0] / 2  # half way
    store.open[2] = _task(2, 50.0)
    loop.wake()
    assert (planner.plans, loop.target) == (2, 2)  # the nearer task first


def test_without_deferral_a_wake_up_at_the_target_plans_at_once() -> None:
    loop, store, clock, planner = _loop(defers=False)
    store.open[1] = _task(1, 100.0)
    loop.wake()
    clock.now = clock.timers[0][0] + 1.0
    store.open[2] = _task(2, 200.0)
    loop.wake()
    assert planner.plans == 2


class FailingStore(Store):
    def __init__(self) -> None:
        super().__init__()
        self.failed: list[tuple[int, str]] = []

    def fail(self, task: LoopTask, reason: str, now_s: float) -> None:
        del self.open[task.id]
        self.failed.append((task.id, reason))


def _zone(corners: list[tuple[float, float]]) -> ExclusionZone:
    points = [offset(DEPOT, north_m=n, east_m=e) for n, e in corners]
    return ExclusionZone(Polygon([(p.lng, p.lat) for p in points]))


def _fly_all(clock: Clock) -> None:
    while clock.timers:
        clock.now = clock.timers[0][0]
        clock.run_due()


def test_the_vehicle_flies_round_a_no_fly_zone_to_its_task_and_home() -> None:
    # A wall between the depot and the task: out round its end and back the same way.
    wall = _zone([(-100, 50), (-100, 70), (100, 70), (100, 50)])
    airspace = Airspace([wall])
    store, clock = FailingStore(), Clock()
    driver = SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT)
    loop = ControlLoop(
        name="RV",
        driver=driver,
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0), airspace=airspace),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        airspace=airspace,
    )
    store.open[1] = _task(1, 150.0)
    loop.wake()
    shown = loop.live_state(0.0)["route"]
    assert len(shown) > 2  # the map draws the turn points before the task
    _fly_all(clock)
    assert [task for task, _ in store.served] == [1]
    assert driver.is_landed_at(clock.now) and driver.position_at(clock.now) == DEPOT
    samples = [driver.position_at(t / 4) for t in range(int(clock.now * 4) + 1)]
    assert not any(wall.holds(p) for p in samples)
    # Round the wall's end and back: about 2 x (100 + 150) m, not 2 x 150 m.
    assert driver.distance_m(clock.now) > 450.0


def test_a_task_no_way_reaches_fails_with_the_reason_and_the_next_is_served() -> None:
    box = Airspace(
        [
            _zone([(-100, 100), (-100, 300), (-80, 300), (-80, 100)]),
            _zone([(80, 100), (80, 300), (100, 300), (100, 100)]),
            _zone([(-100, 100), (-100, 120), (100, 120), (100, 100)]),
            _zone([(-100, 280), (-100, 300), (100, 300), (100, 280)]),
        ]
    )
    store, clock = FailingStore(), Clock()
    loop = ControlLoop(
        name="RV",
        driver=SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT),
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0), airspace=box),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        airspace=box,
    )
    store.open[1] = _task(1, 200.0)  # inside the box of zones
    store.open[2] = _task(2, -100.0)
    loop.wake()
    _fly_all(clock)
    assert [task for task, _ in store.served] == [2]
    assert store.failed == [(1, NO_WAY)]


class StatusStore(Store):
    def __init__(self) -> None:
        super().__init__()
        self.statuses: list[tuple[str, str | None, str]] = []

    def status(self) -> str:
        return self.statuses[-1][0] if self.statuses else ACTIVE

    def set_status(self, status: str, *, expected: str | None = None, reason: str = "") -> None:
        self.statuses.append((status, expected, reason))


class BrokenVehicle(SimVehicle):
    def __init__(self, error: Exception) -> None:
        super().__init__(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT)
        self.error = error

    def fly_to(self, target: Position, now: float) -> float:
        raise self.error


def _failing_flight(error: Exception) -> StatusStore:
    store, clock = StatusStore(), Clock()
    loop = ControlLoop(
        name="RV",
        driver=BrokenVehicle(error),
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0)),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
    )
    store.open[1] = _task(1, 100.0)
    loop.wake()
    assert loop.target is None and store.open  # nothing flown, the task still open
    return store


def test_a_command_that_finds_the_link_down_takes_the_rv_offline_for_link_lost() -> None:
    # The MAVLink driver's own error, with its own words: the RV's reason is the link
    # watch's, whichever of the two sees the dead link first.
    store = _failing_flight(LinkLost("Heli One: the link to the vehicle is down"))
    assert store.statuses == [(OFFLINE, ACTIVE, LINK_LOST)]


def test_a_command_the_autopilot_refuses_takes_the_rv_offline_for_its_words() -> None:
    refusal = PreArmFailed(mavlink.MAV_RESULT_FAILED, ["PreArm: Compass not calibrated"])
    store = _failing_flight(refusal)
    assert store.statuses == [(OFFLINE, ACTIVE, str(refusal))]
    assert "PreArm: Compass not calibrated" in str(refusal)


class Elsewhere:
    """Plans asked for and not made yet (the test makes them when it says)."""

    def __init__(self) -> None:
        self.asked: list[tuple[Any, Position, list[PlanTask], float, Callable[..., None]]] = []

    def __call__(
        self,
        vehicle: str,
        planner: Any,
        current: Position,
        tasks: list[PlanTask],
        now_s: float,
        then: Callable[[list[PlanTask]], None],
    ) -> None:
        self.asked.append((planner, current, tasks, now_s, then))

    def make(self, index: int) -> None:
        planner, current, tasks, now_s, then = self.asked[index]
        then(planner.plan(current, tasks, now_s))


def _loop_planning_elsewhere() -> tuple[ControlLoop, Store, Clock, Elsewhere]:
    store, clock, elsewhere = Store(), Clock(), Elsewhere()
    loop = ControlLoop(
        name="RV",
        driver=SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT),
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0)),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        plan_elsewhere=elsewhere,
    )
    return loop, store, clock, elsewhere


def test_a_plan_made_elsewhere_is_flown_when_it_is_back() -> None:
    loop, store, clock, elsewhere = _loop_planning_elsewhere()
    store.open[1] = _task(1, 100.0)
    loop.wake()
    assert len(elsewhere.asked) == 1
    assert (loop.target, clock.timers) == (None, [])  # nothing flown before the plan is back
    elsewhere.make(0)
    assert loop.target == 1
    assert [task.id for task in loop.route] == [1]
    assert loop.planner.state() == {"route": [1]}
    _fly_all(clock)
    assert [task_id for task_id, _ in store.served] == [1]
    assert len(elsewhere.asked) == 1  # (nothing open after it: no plan to ask for)


def test_a_plan_that_comes_back_after_a_newer_one_was_asked_for_is_dropped() -> None:
    loop, store, clock, elsewhere = _loop_planning_elsewhere()
    store.open[1] = _task(1, 100.0)
    loop.wake()
    store.open[2] = _task(2, -50.0)  # nearer, on the other side
    loop.wake()
    elsewhere.make(0)  # the first plan knew task 1 only: out of date
    assert (loop.target, clock.timers) == (None, [])
    elsewhere.make(1)
    assert loop.target == 2
    assert [task.id for task in loop.route] == [2, 1]


def test_a_planner_that_does_not_retarget_plans_on_the_loops_thread() -> None:
    store, clock, elsewhere = Store(), Clock(), Elsewhere()
    loop = ControlLoop(
        name="RV",
        driver=SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT),
        planner=make_planner("nearest"),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        plan_elsewhere=elsewhere,
    )
    store.open[1] = _task(1, 100.0)
    loop.wake()
    assert (loop.target, elsewhere.asked) == (1, [])


class ReportingVehicle(SimVehicle):
    """A vehicle that reports where it is (as a MAVLink one) and whose estimates are off by
    ``factor``: it gets there in ``factor`` times the time it says (quicker below 1)."""

    def __init__(self, factor: float) -> None:
        super().__init__(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT)
        self.reports_arrival = True
        self.factor = factor
        self.arrivals: list[float] = []  # when it really got to each place it was sent

    def fly_to(self, target: Position, now: float) -> float:
        arrival = super().fly_to(target, now)
        self.arrivals.append(arrival)
        return now + (arrival - now) / self.factor


@pytest.mark.parametrize("factor", [0.25, 2.0], ids=["quicker", "slower"])
def test_a_vehicle_that_reports_arrival_stands_by_from_when_it_is_there(factor: float) -> None:
    store, clock, driver = Store(), Clock(), ReportingVehicle(factor)
    loop = ControlLoop(
        name="RV",
        driver=driver,
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0)),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        config=LoopConfig(standby_s=30.0),
    )
    store.open[1] = _task(1, 100.0)
    loop.wake()
    while clock.timers and not loop.returning:
        clock.now = clock.timers[0][0]
        clock.run_due()
    assert [task for task, _ in store.served] == [1]
    assert loop.returning
    _, at_standby = driver.arrivals  # the task, then the standby position
    # 30 s there from when it is there (within 2 m, looked for every 0.2 s), not from when
    # the estimate said it would be.
    assert clock.now == pytest.approx(at_standby + 30.0, abs=0.25)
