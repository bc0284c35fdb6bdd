"""Flight records (issue 58): every take-off to landing of an RV is a ``Flight``, opened with
the take-off's report and closed with the landing's, in the units of work the control loop
writes anyway: how long and how far it flew (its odometers' gain), how high, its battery at
both ends, the tasks it served with their customers and VVs, and how it ended. The loop on its
own first (what it reports), then over the database on discrete-event time (``platform``)."""

from __future__ import annotations

import pytest
from django.contrib.auth.models import Group

from accounts.roles import PILOT
from fleet.driving import LinkDown
from fleet.geo import Position, ground_distance_m, offset
from fleet.models import Flight, FlightEnd, VehicleCommand
from fleet.simulation import SimVehicle, VehicleSpec
from tests.factories import CustomerFactory, UserFactory, VehicleFactory
from tests.vvm_worker.test_control_loop import DEPOT, Clock, Store
from tests.vvm_worker.test_operator_commands import _carrying
from vvm_worker.control import (
    LANDED_ELSEWHERE,
    LANDED_HOME,
    LINK_LOST_IN_FLIGHT,
    ControlLoop,
    Landing,
    LoopConfig,
    LoopTask,
    VehicleState,
)
from vvm_worker.planning import TravelTime, make_planner
from vvm_worker.services import vehicle_command, vehicle_take_duty, vv_submit

# --- the loop on its own ------------------------------------------------------------------


class FlightStore(Store):
    """A store that keeps the take-offs and landings the loop reports."""

    def __init__(self) -> None:
        super().__init__()
        self.take_offs: list[float] = []
        self.landings: list[Landing] = []

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        if state.took_off_s is not None:
            self.take_offs.append(state.took_off_s)
        if state.landing is not None:
            self.landings.append(state.landing)


class FlakyVehicle(SimVehicle):
    """A simulated vehicle whose link can go down: then every command raises LinkDown."""

    down = False

    def fly_to(self, target: Position, now_s: float) -> float:
        if self.down:
            raise LinkDown("the link to the vehicle is down")
        return super().fly_to(target, now_s)

    def return_to_depot(self, now_s: float) -> float:
        if self.down:
            raise LinkDown("the link to the vehicle is down")
        return super().return_to_depot(now_s)


def _rig(battery_s: float | None = 600.0) -> tuple[ControlLoop, FlightStore, Clock, FlakyVehicle]:
    store, clock = FlightStore(), Clock()
    driver = FlakyVehicle(
        VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0, battery_s=battery_s), DEPOT
    )
    loop = ControlLoop(
        name="RV",
        driver=driver,
        planner=make_planner("nearest", travel_time=TravelTime(10.0, 3.0)),
        store=store,
        scheduler=clock,
        clock=lambda: clock.now,
        config=LoopConfig(battery_s=battery_s),
    )
    return loop, store, clock, driver


def _task(task_id: int, north_m: float, alt: float = 40.0) -> LoopTask:
    return LoopTask(task_id, offset(DEPOT, north_m=north_m, east_m=0.0).with_alt(alt), 1.0, 0.0)


def _run(clock: Clock, until_s: float) -> None:
    while clock.timers and clock.timers[0][0] <= until_s:
        clock.now = clock.timers[0][0]
        clock.run_due()
    clock.now = max(clock.now, until_s)


def test_the_loop_reports_a_flight_from_its_take_off_to_its_landing_at_home() -> None:
    loop, store, clock, driver = _rig()
    store.open[1] = _task(1, 300.0, alt=40.0)
    store.open[2] = _task(2, 200.0, alt=25.0)
    loop.wake()
    _run(clock, 3600.0)
    assert len(store.served) == 2 and driver.is_landed_at(clock.now)
    assert store.take_offs == [0.0]
    (landing,) = store.landings
    assert (landing.took_off_s, landing.how) == (0.0, LANDED_HOME)
    # Its odometers then: everything it flew (one flight), the highest altitude its tasks'.
    assert landing.flight_s == pytest.approx(driver.flight_s(clock.now))
    assert landing.distance_m == pytest.approx(driver.distance_m(clock.now))
    assert landing.max_alt_m == pytest.approx(40.0)
    assert landing.battery_start_pct == 100.0
    assert landing.battery_end_pct == pytest.approx(100 * (1 - landing.flight_s / 600.0), abs=0.1)


def test_a_landing_the_loop_did_not_watch_is_seen_at_the_next_take_off_and_where_it_was() -> None:
    # The vehicle came down away from home while the loop looked elsewhere (an autopilot's
    # own landing): the next take-off ends that flight first, where the vehicle stood.
    loop, store, clock, driver = _rig()
    store.open[1] = _task(1, 400.0)
    loop.wake()
    _run(clock, 20.0)
    down_at = driver.land(clock.now)
    _run(clock, down_at + 1.0)
    assert driver.is_landed_at(clock.now) and not store.landings
    _run(clock, 600.0)  # overdue at its task: sent there anew, from where it stands
    landing = store.landings[0]
    assert landing.how == LANDED_ELSEWHERE
    assert ground_distance_m(driver.position_at(landing.t_s), DEPOT) > 50.0
    assert store.take_offs[:2] == [0.0, landing.t_s], "and a new flight began"


def test_a_link_lost_in_flight_ends_the_flight_there_and_a_vehicle_that_started_aloft_has_none() -> (
    None
):
    loop, store, clock, driver = _rig(battery_s=None)
    store.open[1] = _task(1, 400.0)
    loop.wake()
    store.open[2] = _task(2, 200.0)
    store.set_status = lambda *args, **kwargs: None  # type: ignore[method-assign]
    _run(clock, 15.0)
    driver.down = True
    _run(clock, 600.0)  # served where it arrived, its next command finds the link down
    ((_, served_s),) = store.served
    (landing,) = store.landings
    assert (landing.how, landing.t_s) == (LINK_LOST_IN_FLIGHT, served_s)
    assert landing.battery_start_pct is None is landing.battery_end_pct  # not measured

    aloft, aloft_store, aloft_clock, aloft_driver = _rig()
    aloft_driver.hover_at(DEPOT.with_alt(30.0), 0.0)
    aloft.wake()  # nothing to do: home, and down
    _run(aloft_clock, 600.0)
    assert aloft_driver.is_landed_at(aloft_clock.now)
    assert aloft_store.take_offs == [] and aloft_store.landings == []


# --- over the database --------------------------------------------------------------------

TWO_TASKS = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(%s, 12.8619, %s),
                 tolerance: 2, sensors: [co2]});
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(%s, 12.8617, 30),
                 tolerance: 2, sensors: [co2]});
"""


@pytest.fixture
def pilot(db):
    user = UserFactory(username="pilot-one", is_staff=True)
    user.groups.add(Group.objects.get(name=PILOT))
    return user


def test_a_simulated_mission_is_one_flight_with_its_tasks_customers_vvs_and_pilot(
    platform, ground_station, pilot
) -> None:
    heli = VehicleFactory(name="Heli One", battery_s=1800.0)
    heli.pilots.add(pilot)
    vehicle_take_duty(vehicles=[heli], pilot=pilot, vvm=platform.vvm)
    rig = platform.add_vehicle_loop(heli)
    a, b = CustomerFactory(name="Customer A"), CustomerFactory(name="Customer B")
    one = vv_submit(
        customer=a, name="VV A", program=TWO_TASKS % (48.1111, 55, 48.1121), vvm=platform.vvm
    )
    two = vv_submit(
        customer=b, name="VV B", program=TWO_TASKS % (48.1101, 45, 48.1125), vvm=platform.vvm
    )
    platform.drain()
    end = platform.clock.now_s()
    assert rig.driver.is_landed_at(end)
    flights = list(Flight.objects.filter(vehicle=heli).order_by("started_s"))
    assert flights, "it flew"
    tasks = sum(f.tasks_served for f in flights)
    assert tasks == 4
    for flight in flights:
        assert flight.ended is not None and flight.ended_how == FlightEnd.LANDED_HOME
        assert (flight.pilot, flight.pilot_name) == (pilot, "pilot-one")
        assert flight.duration_s == pytest.approx(flight.ended_s - flight.started_s)
    # Every metre and second the vehicle flew, in its flights (its odometers: the row's too).
    heli.refresh_from_db()
    assert sum(f.distance_m for f in flights) == pytest.approx(rig.driver.distance_m(end))
    assert sum(f.duration_s for f in flights) == pytest.approx(rig.driver.flight_s(end))
    assert heli.distance_m == pytest.approx(rig.driver.distance_m(end))
    assert max(f.max_alt_m for f in flights) == pytest.approx(55.0)
    first = flights[0]
    assert first.battery_start_pct == 100.0
    assert first.battery_end_pct == pytest.approx(100 * (1 - first.duration_s / 1800.0), abs=0.1)
    customers = {c["name"]: c["id"] for f in flights for c in f.customers}
    assert customers == {"Customer A": a.pk, "Customer B": b.pk}
    vvs = {v["name"]: v["id"] for f in flights for v in f.vvs}
    assert vvs == {"VV A": str(one.pk), "VV B": str(two.pk)}


def test_an_operators_land_command_ends_the_flight_where_it_landed(
    platform, ground_station, customer_a
) -> None:
    one, _, rig = _carrying(platform, customer_a)

    def operator() -> None:
        vehicle_command(vehicle=one, command=VehicleCommand.LAND, vvm=platform.vvm)

    platform.queue.call_at(platform.clock.now_s() + 30.0, operator)
    platform.drain()
    flight = Flight.objects.get(vehicle=one)
    assert flight.ended_how == FlightEnd.OPERATOR
    assert flight.tasks_served == 0 and flight.customers == [] and flight.vvs == []
    assert flight.distance_m == pytest.approx(rig.driver.distance_m(platform.clock.now_s()))
    assert 10.0 < flight.max_alt_m <= 40.0
    assert flight.battery_start_pct is None, "no battery configured"
    landed = rig.driver.position_at(platform.clock.now_s())
    assert ground_distance_m(landed, one.depot) > 100.0


def test_an_rv_that_starts_in_the_air_records_its_flights_from_its_first_take_off(
    platform, ground_station, customer_a
) -> None:
    heli = VehicleFactory(name="Heli One")
    rig = platform.add_vehicle_loop(heli, airborne_at=heli.depot.with_alt(30.0))
    platform.queue.call_now(rig.loop.wake)
    platform.drain()  # nothing to do: home and down, no flight of the platform's
    assert rig.driver.is_landed_at(platform.clock.now_s())
    assert not Flight.objects.exists()
    vv_submit(
        customer=customer_a, name="VV", program=TWO_TASKS % (48.1111, 50, 48.1121), vvm=platform.vvm
    )
    platform.drain()
    assert list(Flight.objects.values_list("tasks_served", "ended_how")) == [
        (2, FlightEnd.LANDED_HOME)
    ]
