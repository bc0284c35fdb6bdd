"""An operator's "return home now" and "land now" (issue 26): the control loop obeys each once,
where the vehicle is, and sends it nowhere else; over the database, the service puts the RV
into maintenance, its VVs move on, and its loop takes the command exactly once."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from fleet.geo import Position, ground_distance_m, offset
from fleet.models import Vehicle, VehicleCommand, VehicleStatus
from fleet.simulation import SimVehicle, VehicleSpec
from missions.models import VVStatus
from tests.factories import VehicleFactory
from tests.vvm_worker.test_control_loop import DEPOT, Clock, Store
from vvm_worker.control import (
    LAND,
    MAINTENANCE,
    RETURN_HOME,
    Area,
    ControlLoop,
    LoopConfig,
    LoopTask,
    OperatorCommand,
)
from vvm_worker.planning import TravelTime, make_planner
from vvm_worker.services import (
    VehicleRemoved,
    vehicle_command,
    vehicle_command_take,
    vehicle_set_status,
    vv_submit,
)

# --- the loop on its own ------------------------------------------------------------------


class CommandStore(Store):
    """A store with an operator: a command waits until the loop takes it (once)."""

    def __init__(self) -> None:
        super().__init__()
        self.waiting: OperatorCommand | None = None
        self.taken: list[OperatorCommand] = []
        self._status = "active"

    def status(self) -> str:
        return self._status

    def give(self, name: str) -> None:
        """The operator's command: the RV is out of service, the command waits."""
        self._status = MAINTENANCE
        self.open.clear()  # its VVs' tasks move to other RVs
        self.waiting = OperatorCommand(name, f"asked {len(self.taken)}")

    def take_command(self) -> OperatorCommand | None:
        command, self.waiting = self.waiting, None
        if command is not None:
            self.taken.append(command)
        return command

    def open_tasks(self) -> Sequence[LoopTask]:
        return super().open_tasks()


def _rig() -> tuple[ControlLoop, CommandStore, Clock, SimVehicle]:
    store, clock = CommandStore(), Clock()
    driver = SimVehicle(VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0), DEPOT)
    loop = ControlLoop(
        name="RV",
        driver=driver,
        planner=make_planner("latency", travel_time=TravelTime(10.0, 3.0)),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        config=LoopConfig(standby_s=60.0),
    )
    return loop, store, clock, driver


def _far_task() -> LoopTask:
    return LoopTask(1, offset(DEPOT, north_m=300.0, east_m=400.0, up_m=40.0), 1.0, 0.0, vv="vv-1")


def _run(clock: Clock, until_s: float) -> None:
    """Run the loop's timers up to ``until_s`` (the clock ends there)."""
    while clock.timers and clock.timers[0][0] <= until_s:
        clock.now = clock.timers[0][0]
        clock.run_due()
    clock.now = until_s


def _in_flight(
    loop: ControlLoop, store: CommandStore, clock: Clock, driver: SimVehicle
) -> Position:
    store.open[1] = _far_task()
    loop.wake()
    _run(clock, 25.0)  # up, and on the way
    assert driver.phase_at(clock.now) == "cruise"
    return driver.position_at(clock.now)


def test_land_now_lands_where_the_vehicle_is_and_it_stays_there() -> None:
    loop, store, clock, driver = _rig()
    here = _in_flight(loop, store, clock, driver)
    state = loop.live_state(clock.now)
    assert state["activity"] == "flying to a task"
    assert state["next_task"]["vv"] == "vv-1" and state["next_task"]["eta_s"] > 0
    store.give(LAND)
    loop.wake()
    assert loop.live_state(clock.now)["activity"] == "landing here"
    assert loop.live_state(clock.now)["command"] == {"name": "land", "asked": "asked 0"}
    touchdown = clock.now + here.alt / 3.0  # straight down at the climb rate
    _run(clock, touchdown + 1.0)
    assert driver.is_landed_at(clock.now)
    assert ground_distance_m(driver.position_at(clock.now), here) < 0.01, "where it was"
    assert ground_distance_m(driver.position_at(clock.now), DEPOT) > 100.0
    # Other wake-ups (a sweep, a fleet change) send it nowhere: it is in maintenance.
    loop.wake()
    _run(clock, clock.now + 300.0)
    assert driver.is_landed_at(clock.now)
    assert ground_distance_m(driver.position_at(clock.now), here) < 0.01
    assert store.taken == [OperatorCommand(LAND, "asked 0")], "taken once"
    assert loop.live_state(clock.now)["activity"] == "landed"


def test_a_landing_holds_when_the_loop_plans_again_before_touchdown() -> None:
    loop, store, clock, driver = _rig()
    here = _in_flight(loop, store, clock, driver)
    store.give(LAND)
    loop.wake()
    clock.now += 2.0  # descending
    loop.wake()  # a plan meanwhile: still landing here, not home
    assert loop.live_state(clock.now)["activity"] == "landing here"
    _run(clock, clock.now + 60.0)
    assert driver.is_landed_at(clock.now)
    assert ground_distance_m(driver.position_at(clock.now), here) < 0.01


def test_return_home_now_flies_home_at_once_and_lands_there() -> None:
    loop, store, clock, driver = _rig()
    _in_flight(loop, store, clock, driver)
    store.give(RETURN_HOME)
    loop.wake()
    state = loop.live_state(clock.now)
    assert (state["activity"], state["next_task"]) == ("returning home", None)
    _run(clock, clock.now + 120.0)
    assert driver.is_landed_at(clock.now) and driver.position_at(clock.now) == DEPOT
    assert [c.name for c in store.taken] == [RETURN_HOME]


def test_return_home_after_a_landing_in_the_field_takes_off_and_flies_home() -> None:
    loop, store, clock, driver = _rig()
    _in_flight(loop, store, clock, driver)
    store.give(LAND)
    loop.wake()
    _run(clock, clock.now + 60.0)
    assert driver.is_landed_at(clock.now) and driver.position_at(clock.now) != DEPOT
    store.give(RETURN_HOME)
    loop.wake()
    assert loop.live_state(clock.now)["activity"] == "returning home"
    _run(clock, clock.now + 30.0)
    assert not driver.is_landed_at(clock.now), "up again"
    _run(clock, clock.now + 120.0)
    assert driver.is_landed_at(clock.now) and driver.position_at(clock.now) == DEPOT
    assert [c.name for c in store.taken] == [LAND, RETURN_HOME]


def test_the_simulated_vehicle_reports_its_ground_speed() -> None:
    loop, store, clock, driver = _rig()
    assert driver.speed_at(0.0) == 0.0  # landed
    _in_flight(loop, store, clock, driver)
    assert driver.speed_at(clock.now) == pytest.approx(10.0)
    store.give(LAND)
    loop.wake()
    assert driver.speed_at(clock.now + 0.1) == 0.0  # straight down


# --- over the database ------------------------------------------------------------------------

FAR = """
var co2 = VV.sensor.get('CO2');
var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1095, 12.8632, 40),
                         tolerance: 2, sensors: [co2]});
VV.storage.store('co2', d[0]);
"""


def _carrying(platform: Any, customer: Any) -> tuple[Vehicle, Any, Any]:
    """Heli One taking off for a VV's task, Heli Two (slower) in the same area to take it."""
    one = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(one)
    platform.add_vehicle_loop(VehicleFactory(name="Heli Two", max_speed_mps=2.0))
    vv = vv_submit(customer=customer, name="VV", program=FAR, vvm=platform.vvm)
    rig = platform.rigs[one.pk]
    platform.drain(
        until=lambda: (
            vv.tasks.filter(vehicle=one).exists()
            and not rig.driver.is_landed_at(platform.clock.now_s())
        )
    )
    return one, vv, rig


@pytest.mark.parametrize("command", [VehicleCommand.LAND, VehicleCommand.RETURN_HOME])
def test_an_operators_command_moves_the_vvs_on_and_the_rv_obeys_it_once(
    platform, ground_station, customer_a, command
) -> None:
    one, vv, rig = _carrying(platform, customer_a)
    asked: dict[str, Any] = {}

    def operator() -> None:  # half way to the task
        asked["here"] = rig.driver.position_at(platform.clock.now_s())
        asked["saved"] = vehicle_command(
            vehicle=one, command=command, vvm=platform.vvm, reason="asked by the test"
        )

    platform.queue.call_at(platform.clock.now_s() + 30.0, operator)
    platform.drain()
    saved, here = asked["saved"], asked["here"]
    assert (saved.status, saved.status_reason) == (VehicleStatus.MAINTENANCE, "asked by the test")
    assert (saved.command, saved.command_taken) == (command, None)
    assert here.alt > 10.0 and ground_distance_m(here, one.depot) > 100.0, "in flight"
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert vv.tasks.get().vehicle.name == "Heli Two", "its VV moved on, as for maintenance"
    one.refresh_from_db()
    assert one.status == VehicleStatus.MAINTENANCE, "nothing sends it out again"
    assert one.command_taken is not None
    landed_at = rig.driver.position_at(platform.clock.now_s())
    assert rig.driver.is_landed_at(platform.clock.now_s())
    if command == VehicleCommand.LAND:
        assert ground_distance_m(landed_at, here) < 0.01
    else:
        assert landed_at == one.depot
    # Taken once: the same command cannot be taken again.
    assert not vehicle_command_take(
        vehicle_id=one.pk, command=command, asked=saved.command_requested
    )


def test_a_newer_command_replaces_one_not_taken_yet(db, vvm_factory) -> None:
    vvm = vvm_factory()
    heli = VehicleFactory(name="Heli One")
    first = vehicle_command(vehicle=heli, command=VehicleCommand.LAND, vvm=vvm)
    second = vehicle_command(vehicle=heli, command=VehicleCommand.RETURN_HOME, vvm=vvm)
    # A loop that read the first one takes nothing: it reads the second with the status.
    assert not vehicle_command_take(
        vehicle_id=heli.pk, command=VehicleCommand.LAND, asked=first.command_requested
    )
    assert vehicle_command_take(
        vehicle_id=heli.pk, command=VehicleCommand.RETURN_HOME, asked=second.command_requested
    )
    assert vvm.dispatcher.vehicles == [heli.pk, heli.pk], "its worker heard of each"


def test_a_removed_rv_takes_no_command(db, vvm_factory) -> None:
    vvm = vvm_factory()
    heli = VehicleFactory(name="Heli One")
    vehicle_set_status(vehicle=heli, status=VehicleStatus.REMOVED, vvm=vvm)
    with pytest.raises(VehicleRemoved, match="Heli One was removed from the fleet"):
        vehicle_command(vehicle=heli, command=VehicleCommand.LAND, vvm=vvm)
    heli.refresh_from_db()
    assert (heli.status, heli.command) == (VehicleStatus.REMOVED, "")


class LakeStore(CommandStore):
    """A sub's store: its altitudes are depths, down to 30 m."""

    def area(self) -> Area:
        return Area(super().area().polygon, -30.0, 0.0)


def test_a_sub_sent_home_after_surfacing_comes_home_on_the_surface() -> None:
    store, clock = LakeStore(), Clock()
    spec = VehicleSpec(max_speed_mps=2.0, climb_rate_mps=0.5, kind="underwater", dive_rate_mps=0.5)
    driver = SimVehicle(spec, DEPOT)
    loop = ControlLoop(
        name="Sub",
        driver=driver,
        planner=make_planner("latency", travel_time=TravelTime(2.0, 0.5, dive_rate_mps=0.5)),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        config=LoopConfig(standby_s=60.0),
    )
    store.open[1] = LoopTask(
        1, offset(DEPOT, north_m=100.0, east_m=0.0, up_m=-10.0), 1.0, 0.0, vv="vv-1"
    )
    loop.wake()
    _run(clock, 40.0)
    assert driver.position_at(clock.now).alt < 0, "under way, below the surface"
    store.give(LAND)
    loop.wake()
    _run(clock, clock.now + 60.0)
    surfaced = driver.position_at(clock.now)
    assert driver.is_landed_at(clock.now) and surfaced.alt == 0.0
    store.give(RETURN_HOME)
    loop.wake()
    depths = []
    while not (driver.is_landed_at(clock.now) and driver.position_at(clock.now) == DEPOT):
        assert clock.now < 600.0, "home within ten minutes"
        _run(clock, clock.now + 1.0)
        depths.append(driver.position_at(clock.now).alt)
    assert max(depths) == 0.0 and min(depths) == 0.0, "on the surface all the way"
