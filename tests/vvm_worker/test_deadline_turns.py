"""An RV's control loop and service classes' deadlines: a request whose deadline the plan
would miss turns the vehicle mid-leg (a simulated vehicle, and a MAVLink copter over a real
link to mavsim), one whose deadline is later never does, and the task left is served after,
once."""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Sequence
from typing import Any

import pytest
from shapely.geometry import Polygon

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavlinkDriver, MavSim
from fleet.mavlink.wire import mavlink
from fleet.simulation import SimVehicle, VehicleSpec
from tests.fleet.mavlink.conftest import DEPOT as COPTER_HOME
from tests.fleet.mavlink.conftest import SPEC, free_udp_port, sim_clock
from tests.polling import wait_until
from vvm_worker.control import ACTIVE, Area, ControlLoop, LoopTask, VehicleState
from vvm_worker.planning import TravelTime, make_planner

DEPOT = Position(47.0, 8.0, 0.0)


class Store:
    """An RV's open tasks in memory, and what it served when."""

    def __init__(self, home: Position) -> None:
        self.home = home
        self.open: dict[int, LoopTask] = {}
        self.served: list[tuple[int, float]] = []

    def open_tasks(self) -> Sequence[LoopTask]:
        return sorted(self.open.values(), key=lambda t: (t.requested_s, t.id))

    def status(self) -> str:
        return ACTIVE

    def set_status(self, status: str, *, expected: str | None = None, reason: str = "") -> None:
        raise AssertionError(f"no status change expected here: {status} ({reason})")

    def take_command(self) -> None:
        return None

    def complete(self, task: LoopTask, readings: list[dict[str, Any]], now_s: float) -> None:
        del self.open[task.id]
        self.served.append((task.id, now_s))

    def fail(self, task: LoopTask, reason: str, now_s: float) -> None:
        raise AssertionError(f"task {task.id} failed: {reason}")

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        pass

    def area(self) -> Area:
        ring = [
            offset(self.home, north_m=n, east_m=e)
            for n, e in ((-900, -900), (900, -900), (900, 900), (-900, 900))
        ]
        return Area(Polygon([(p.lng, p.lat) for p in ring]), 0.0, 120.0)

    def aboard(self) -> list[dict[str, Any]]:
        return []


class Timers:
    """The loop's timers, run when the test says, on the clock it is given."""

    def __init__(self, clock: Callable[[], float]) -> None:
        self.clock = clock
        self.timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()

    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self.timers, (t_s, next(self._seq), fn))

    def run_due(self) -> None:
        now = self.clock()
        while self.timers and self.timers[0][0] <= now:
            heapq.heappop(self.timers)[2]()


class EventTime:
    """Discrete time: ``now`` moves only when the test moves it."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def simulated_loop(planner: str) -> tuple[ControlLoop, Store, Timers, EventTime, SimVehicle]:
    store, time = Store(DEPOT), EventTime()
    timers = Timers(time)
    driver = SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT)
    loop = ControlLoop(
        name="RV",
        driver=driver,
        planner=make_planner(planner, travel_time=TravelTime(10.0, 3.0)),
        store=store,
        scheduler=timers,
        clock=time,
    )
    return loop, store, timers, time, driver


def fly_until(timers: Timers, time: EventTime, t_s: float) -> None:
    while timers.timers and timers.timers[0][0] <= t_s:
        time.now = timers.timers[0][0]
        timers.run_due()
    time.now = t_s


def point(home: Position, north_m: float, east_m: float, up_m: float = 10.0) -> Position:
    return offset(home, north_m=north_m, east_m=east_m, up_m=up_m)


@pytest.mark.parametrize("planner", ["fcfs", "latency"])
def test_a_request_whose_deadline_the_plan_would_miss_turns_the_rv_mid_leg(planner: str) -> None:
    loop, store, timers, time, driver = simulated_loop(planner)
    # A standard request 400 m east, due in 120 s: the RV takes off and flies to it.
    store.open[1] = LoopTask(1, point(DEPOT, 0.0, 400.0), 1.0, 0.0, deadline_s=120.0)
    loop.wake()
    fly_until(timers, time, 20.0)
    assert loop.target == 1 and not driver.is_landed_at(20.0)
    here = driver.position_at(20.0)
    # A premium request 150 m north of it, due in 30 s: after task 1 it would be reached at
    # about 60 s. The RV turns now, in the air.
    premium = point(here, 150.0, 0.0)
    store.open[2] = LoopTask(2, premium, 1.0, 20.0, deadline_s=50.0)
    loop.wake()
    assert loop.target == 2
    assert not driver.is_landed_at(20.0)
    fly_until(timers, time, 400.0)
    # The premium task in time, then the one left mid-leg: each served once.
    assert [task_id for task_id, _ in store.served] == [2, 1]
    assert dict(store.served)[2] <= 50.0


@pytest.mark.parametrize("due_in_s", [25.0, 60.0])
def test_a_request_whose_deadline_is_later_never_turns_the_rv(due_in_s: float) -> None:
    # fcfs keeps its target until it gets there; only a deadline could turn it.
    loop, store, timers, time, driver = simulated_loop("fcfs")
    far = point(DEPOT, 0.0, 400.0)
    store.open[1] = LoopTask(1, far, 1.0, 0.0, deadline_s=40.0)  # due at 40 s
    loop.wake()
    fly_until(timers, time, 10.0)
    # 150 m behind the RV: after task 1 it would be reached at about 90 s, late either way.
    behind = point(driver.position_at(10.0), 0.0, -150.0)
    store.open[2] = LoopTask(2, behind, 1.0, 10.0, deadline_s=10.0 + due_in_s)
    loop.wake()
    if due_in_s < 30.0:  # due before task 1: the RV turns for it
        assert loop.target == 2
    else:  # due after task 1 (yet late if served second): the RV flies on
        assert loop.target == 1
    fly_until(timers, time, 400.0)
    assert sorted(task_id for task_id, _ in store.served) == [1, 2]


def test_a_mavlink_copter_turns_mid_leg_for_an_earlier_deadline() -> None:
    speed = 20.0
    port = free_udp_port()
    sim = MavSim(f"udpin:127.0.0.1:{port}", spec=SPEC, depot=COPTER_HOME, speed=speed).start()
    clock = sim_clock(speed)
    driver = MavlinkDriver(
        f"udpout:127.0.0.1:{port}",
        spec=SPEC,
        depot=COPTER_HOME,
        clock=clock,
        telemetry_hz=50.0,
        command_timeout_s=0.5,
    )
    try:
        driver.connect(timeout_s=5.0)
        store, timers = Store(COPTER_HOME), Timers(clock)
        loop = ControlLoop(
            name="Heli One",
            driver=driver,
            planner=make_planner("fcfs", travel_time=TravelTime(10.0, 3.0)),
            store=store,
            scheduler=timers,
            clock=clock,
        )
        # A standard request at the area's far corner, due in 120 s.
        far = point(COPTER_HOME, -480.0, 250.0, 40.0)
        store.open[1] = LoopTask(1, far, 5.0, clock(), deadline_s=clock() + 120.0)
        loop.wake()

        def out_100_m() -> bool:
            timers.run_due()
            return distance_m(sim.position(), COPTER_HOME) > 100.0 and not sim.on_ground

        wait_until(out_100_m, timeout=30, what="the copter 100 m out towards task 1")
        # A premium request back near home, due in 25 s: after task 1 it would be late.
        now = clock()
        premium = point(COPTER_HOME, -60.0, -60.0, 30.0)
        store.open[2] = LoopTask(2, premium, 5.0, now, deadline_s=now + 25.0)
        loop.wake()
        assert loop.target == 2  # turned, in the air: a new position target, no landing

        def both_served() -> bool:
            timers.run_due()
            return len(store.served) == 2

        wait_until(both_served, timeout=60, what="both tasks served")
        assert [task_id for task_id, _ in store.served] == [2, 1]
        assert dict(store.served)[2] <= now + 25.0
        # One take-off for both: the copter turned in flight and never landed in between.
        assert len(sim.commands_seen(mavlink.MAV_CMD_NAV_TAKEOFF)) == 1
    finally:
        driver.close()
        sim.stop()
