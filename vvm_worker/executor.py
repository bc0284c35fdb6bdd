"""The task executor: one RV's control loop (plan, fly, read sensors, resume VVs).

The loop keeps the route over the open tasks of every VV aboard with its planner, flies to
the next task through its driver, reads the sensors there for every task within tolerance
and resumes those VVs (``task_complete``). It asks the planner again when it arrives and,
when the planner ``retargets``, whenever work is added in flight. With nothing left to do it
waits in the air at its standby position for a while (planners that ``stand_by``) and then
flies home and lands. Time comes from a scheduler: the discrete-event queue of ``simulate``,
or real time in a worker.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, Protocol

from fleet.geo import Position, distance_m
from fleet.mavlink.errors import MavlinkError
from fleet.models import SensorType, Vehicle, VehicleStatus
from missions.models import ACTIVE_STATUSES, Task, TaskStatus, VirtualVehicle
from vvm_worker.planning import Planner, PlanTask, standby_position
from vvm_worker.sensing import read_sensors
from vvm_worker.services import VVM, task_complete, vehicle_record_state, vehicle_set_status
from vvm_worker.services.base import announcing

logger = logging.getLogger("cpcc.executor")

# A vehicle at its target serves every open task within the task's tolerance plus this much
# (floating-point slack of the kinematics).
_REACH_SLACK_M = 1e-3
# A vehicle not there at its estimated arrival is looked at this often, and sent there anew
# when this late.
_ARRIVAL_POLL_S = 0.2
_ARRIVAL_OVERDUE_S = 60.0
_SDC_TTL_S = 10.0
# Altitudes of this many tasks served last place the standby position.
_RECENT_TASKS = 20


class Scheduler(Protocol):
    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        """Run fn when the platform clock reaches t_s."""
        ...


class Driver(Protocol):
    """The vehicle link: a simulated vehicle or a MAVLink autopilot."""

    def fly_to(self, target: Position, now_s: float) -> float: ...
    def return_to_depot(self, now_s: float) -> float: ...
    def position_at(self, t: float) -> Position: ...
    def phase_at(self, t: float) -> str: ...
    def is_landed_at(self, t: float) -> bool: ...
    def distance_m(self, t: float) -> float: ...
    def flight_s(self, t: float) -> float: ...
    def battery_remaining_s(self, t: float) -> float | None: ...
    def time_to_s(self, target: Position, now_s: float) -> float: ...
    def time_home_s(self, start: Position) -> float: ...
    def recharge(self, now_s: float, duration_s: float) -> float: ...
    def has_arrived(self, target: Position, tolerance_m: float, now_s: float) -> bool: ...


class VehicleLoop:
    """The control loop of one RV."""

    def __init__(
        self,
        *,
        vehicle_id: int,
        driver: Driver,
        planner: Planner,
        vvm: VVM,
        scheduler: Scheduler,
        battery_s: float | None = None,
        reserve: float = 0.0,
        recharge_s: float = 0.0,
        standby_s: float = 0.0,
    ) -> None:
        self.vehicle_id = vehicle_id
        self.driver = driver
        self.planner = planner
        self.vvm = vvm
        self.scheduler = scheduler
        self.battery_s = battery_s
        # Endurance kept for the unexpected: never planned away (seconds of flight).
        self.reserve_s = reserve * battery_s if battery_s else 0.0
        self.recharge_s = recharge_s
        self.standby_s = standby_s
        self.standby_until: float | None = None  # waiting in the air for work until then
        self._recent_alts: list[float] = []
        self._charged_at: float | None = None  # when a charge under way is done
        self.target: int | None = None  # the task the vehicle is flying to
        self.returning = False
        self._token = 0  # invalidates the arrival of a leg that was replaced
        self._sdc: tuple[float, dict[str, dict[str, Any]]] | None = None
        # What the live map shows of this RV between two plans: its status, the VVs aboard
        # and the open tasks in the order it means to serve them.
        self.status = VehicleStatus.ACTIVE
        self.aboard: list[dict[str, Any]] = []
        self.route: list[Position] = []
        # What _save_state wrote last: (position, phase, odometer, flight time, planner state).
        self._last_state: tuple[Any, ...] | None = None
        self._changes = 0  # changes announced by `changed`
        self._planned_at_change = 0  # how many of them the last plan had seen

    # --- events ------------------------------------------------------------------------------

    def wake(self) -> None:
        """The vehicle's tasks or status changed: re-plan, unless its target still stands and
        its planner keeps targets until it gets there."""
        now = self.vvm.clock.now_s()
        if (
            not self.planner.retargets
            and self.target is not None
            and self._assigned().filter(pk=self.target).exists()
        ):
            if announcing(self.vvm):  # the map shows new work and VVs at once
                here = self.driver.position_at(now)
                plan = [_plan_task(t) for t in self._assigned()]
                self.route = [t.position for t in self.planner.route(here, plan, now)]
                self.aboard = self._aboard()
            return
        self._plan(now)

    def changed(self) -> Callable[[], None]:
        """The vehicle's tasks or status were just changed (committed): the wake-up to run
        for it, which does nothing if the loop has planned in the meantime (it saw the
        change then): a VV resumed on this RV while it serves its stop needs no second plan."""
        self._changes += 1
        seen = self._changes

        def wake_unless_planned() -> None:
            if self._planned_at_change < seen:
                self.wake()

        return wake_unless_planned

    def _arrive(self, token: int, target: Position, tolerance_m: float, due_s: float) -> None:
        if token != self._token:
            return
        now = self.vvm.clock.now_s()
        if not self.driver.has_arrived(target, tolerance_m, now):
            # A real vehicle is there when its telemetry says so, not when the estimate said:
            # look again shortly, and fly there anew if it is far overdue (a gust, a fence).
            if now - due_s > _ARRIVAL_OVERDUE_S:
                logger.warning(
                    "arrival overdue: flying there again", extra={"vehicle": self.vehicle_id}
                )
                self._plan(now)
            else:
                self.scheduler.call_at(
                    now + _ARRIVAL_POLL_S, lambda: self._arrive(token, target, tolerance_m, due_s)
                )
            return
        self.target = None
        # The end of the leg is on the track of the VVs aboard, before any of them leaves, and
        # the vehicle's row says it is here: a VV migrating off it now records this position.
        self._save_state(now)
        here = self.driver.position_at(now)
        served = [
            t
            for t in self._assigned().order_by("requested_s", "id")
            if distance_m(here, t.position) <= t.tolerance_m + _REACH_SLACK_M
        ]
        catalog = self._catalog()
        for task in served:
            self._recent_alts = [*self._recent_alts[1 - _RECENT_TASKS :], task.alt]
            readings = read_sensors(
                field=self.vvm.field,
                sensors=[catalog[name] for name in task.sensors],
                position=here,
                time_s=now,
                epoch_ms=self.vvm.clock.epoch_ms(now),
                battery_fraction=self._battery_fraction(now),
                seed=self.vvm.world_seed,
            )
            task_complete(
                task_id=task.pk,
                readings=readings,
                vvm=self.vvm,
                vehicle_id=self.vehicle_id,
                vv_id=task.vv_id,
            )
        self._plan(now)

    def _landed(self, token: int, due_s: float) -> None:
        if token != self._token:
            return
        now = self.vvm.clock.now_s()
        if not self.driver.is_landed_at(now):
            if now - due_s > _ARRIVAL_OVERDUE_S:
                logger.warning(
                    "landing overdue: returning again", extra={"vehicle": self.vehicle_id}
                )
                self._plan(now)
            else:
                self.scheduler.call_at(now + _ARRIVAL_POLL_S, lambda: self._landed(token, due_s))
            return
        self.returning = False
        if self.status == VehicleStatus.CHARGING:
            self._charge(now)
        self._save_state(now)

    # --- the battery ---------------------------------------------------------------------------

    def _within_battery(self, now: float, target: Position) -> bool:
        """Whether the vehicle can fly to ``target`` and home from there with its reserve left."""
        remaining = self.driver.battery_remaining_s(now)
        if remaining is None:
            return True
        need = self.driver.time_to_s(target, now) + self.driver.time_home_s(target)
        if remaining - need >= self.reserve_s:
            return True
        if self.driver.is_landed_at(now) and remaining >= (self.battery_s or 0.0):
            # Full, and still too far: no charge helps; the mapper does not know the range.
            logger.warning("task beyond the battery's range", extra={"vehicle": self.vehicle_id})
            return True
        return False

    def _run_low(self) -> None:
        """Hand the work over and go home to recharge: the VVs aboard move to RVs that can
        serve them (or wait), and this RV takes no work until it is full again."""
        logger.info("battery low: recharging", extra={"vehicle": self.vehicle_id})
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        vehicle_set_status(vehicle=vehicle, status=VehicleStatus.CHARGING, vvm=self.vvm)
        self.status = VehicleStatus.CHARGING

    def _charge(self, now: float) -> None:
        if self._charged_at is None:
            self._charged_at = self.driver.recharge(now, self.recharge_s)
            self.scheduler.call_at(self._charged_at, self._charged)

    def _charged(self) -> None:
        self._charged_at = None
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        if vehicle.status == VehicleStatus.CHARGING:  # unless the provider decided otherwise
            vehicle_set_status(vehicle=vehicle, status=VehicleStatus.ACTIVE, vvm=self.vvm)
        self.wake()

    # --- planning ------------------------------------------------------------------------------

    def _assigned(self) -> Any:
        return Task.objects.filter(vehicle_id=self.vehicle_id, status=TaskStatus.OPEN)

    def _plan(self, now: float) -> None:
        self._planned_at_change = self._changes
        status = Vehicle.objects.values_list("status", flat=True).get(pk=self.vehicle_id)
        self.status = VehicleStatus(status)
        tasks = list(self._assigned()) if status == VehicleStatus.ACTIVE else []
        here = self.driver.position_at(now)
        choice = None
        self.route = []
        if tasks:
            plan = [_plan_task(t) for t in tasks]
            choice = self.planner.next_task(here, plan, now)
            self.route = [t.position for t in self.planner.route(here, plan, now)]
            if choice is not None and not self._within_battery(now, choice.position):
                self._run_low()
                choice, self.route = None, []
        if self.status == VehicleStatus.CHARGING and self.driver.is_landed_at(now):
            self._charge(now)
        if choice is not None and choice.id == self.target and not self.returning:
            self._save_state(now)  # still the best target: fly on
            return
        self._token += 1
        token = self._token
        if choice is not None:
            self.target = choice.id
            self.returning = False
            self.standby_until = None
            tolerance_m = next(t.tolerance_m for t in tasks if t.pk == choice.id)
            try:
                arrival = self.driver.fly_to(choice.position, now)
            except MavlinkError as exc:
                self._failed(exc)
                return
            self.scheduler.call_at(
                arrival, lambda: self._arrive(token, choice.position, tolerance_m, arrival)
            )
        else:
            self.target = None
            if not self.driver.is_landed_at(now) and not self._stand_by(now, token):
                self._go_home(now, token)
        self._save_state(now)

    def _go_home(self, now: float, token: int) -> None:
        self.returning = True
        self.standby_until = None
        try:
            landing = self.driver.return_to_depot(now)
        except MavlinkError as exc:
            self._failed(exc)
            return
        self.scheduler.call_at(landing, lambda: self._landed(token, landing))

    def _stand_by(self, now: float, token: int) -> bool:
        """Wait in the air at the standby position, if the planner wants it and the battery
        allows it (there, a while, and home with the reserve left). False: fly home."""
        if (
            not self.planner.stands_by
            or self.standby_s <= 0
            or self.status != VehicleStatus.ACTIVE
            or self.returning
        ):
            return False
        if self.standby_until is not None:
            if now >= self.standby_until:
                return False
            self.scheduler.call_at(self.standby_until, lambda: self._standby_over(token))
            return True  # already waiting (or on the way there): keep its deadline
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        spot = standby_position(
            vehicle.area_polygon,
            self._recent_alts,
            min_altitude_m=vehicle.min_altitude_m,
            max_altitude_m=vehicle.max_altitude_m,
        )
        wait_s = self.standby_s
        remaining = self.driver.battery_remaining_s(now)
        if remaining is not None:
            spare = remaining - self.reserve_s - self.driver.time_to_s(spot, now)
            wait_s = min(wait_s, spare - self.driver.time_home_s(spot))
            if wait_s <= 0:
                return False
        try:
            there = self.driver.fly_to(spot, now)
        except MavlinkError as exc:
            self._failed(exc)
            return True
        self.standby_until = there + wait_s
        self.scheduler.call_at(self.standby_until, lambda: self._standby_over(token))
        return True

    def _standby_over(self, token: int) -> None:
        if token != self._token:
            return
        now = self.vvm.clock.now_s()
        self._token += 1
        self._go_home(now, self._token)
        self._save_state(now)

    def _failed(self, exc: Exception) -> None:
        """The vehicle cannot be flown (its link, its autopilot refused, a pilot took over):
        it leaves service so that its VVs move on; the operator returns it (or its worker,
        once the link is back)."""
        logger.error("vehicle out of service: %s", exc, extra={"vehicle": self.vehicle_id})
        self.target = None
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        if vehicle.status == VehicleStatus.ACTIVE:
            vehicle_set_status(vehicle=vehicle, status=VehicleStatus.MAINTENANCE, vvm=self.vvm)
        self.status = VehicleStatus.MAINTENANCE

    def _catalog(self) -> dict[str, dict[str, Any]]:
        # The SDC changes rarely; read it again now and then, not at every stop.
        now = time.monotonic()
        if self._sdc is None or now - self._sdc[0] > _SDC_TTL_S:
            self._sdc = (now, {s.name: s.as_catalog_entry() for s in SensorType.objects.all()})
        return self._sdc[1]

    def _battery_fraction(self, now: float) -> float | None:
        remaining = self.driver.battery_remaining_s(now)
        if remaining is None or not self.battery_s:
            return None
        return max(0.0, min(1.0, remaining / self.battery_s))

    def _aboard(self) -> list[dict[str, Any]]:
        return [
            {"id": str(pk), "name": name, "customer": customer_id}
            for pk, name, customer_id in VirtualVehicle.objects.filter(
                host_rv_id=self.vehicle_id, status__in=ACTIVE_STATUSES
            )
            .order_by("submitted_s", "id")
            .values_list("pk", "name", "customer_id")
        ]

    def live_state(self, now: float) -> dict[str, Any]:
        """The RV as the live map shows it now (positions as [lat, lng])."""
        here = self.driver.position_at(now)
        ahead = self.route if not self.returning else []
        return {
            "id": self.vehicle_id,
            "lat": here.lat,
            "lng": here.lng,
            "alt": here.alt,
            "phase": self.driver.phase_at(now),
            "status": self.status,
            "battery": self._battery_fraction(now),
            "vvs": self.aboard,
            "route": [[here.lat, here.lng]] + [[p.lat, p.lng] for p in ahead],
            "t": self.vvm.clock.epoch_ms(now) / 1000,
        }

    def _save_state(self, now: float) -> None:
        here = self.driver.position_at(now)
        # A leg is straight: its two ends are the path the VVs aboard travel.
        moved = self._last_state is None or here != self._last_state[0]
        if moved or announcing(self.vvm):  # the track and the map need the VVs aboard
            self.aboard = self._aboard()
        state = (
            here,
            self.driver.phase_at(now),
            self.driver.distance_m(now),
            self.driver.flight_s(now),
            self.planner.state(),
        )
        if state == self._last_state:
            return  # the row says all this already (a second look at the same moment)
        position, phase, distance, flight, planner_state = state
        vehicle_record_state(
            vehicle_id=self.vehicle_id,
            t_s=now,
            carrying=[vv["id"] for vv in self.aboard] if moved else [],
            position=position,
            phase=phase,
            distance_m=distance,
            flight_s=flight,
            planner_state=planner_state,
        )
        self._last_state = state  # only once written: work redone after an outage writes it


def _plan_task(task: Task) -> PlanTask:
    """A task as the planner sees it; the tasks of one request (an executeAll batch) share a
    group."""
    return PlanTask(task.pk, task.position, task.requested_s, group=f"{task.vv_id}:{task.q}")
