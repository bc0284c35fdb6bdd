"""The control loop of one RV (the paper's task executor): plan, fly, read sensors, hand the
readings over, land, recharge, stand by.

Pure: the loop knows its vehicle through a ``Driver`` (``fleet.driving``), its work through a
``Store`` (the database for the platform, memory for the planners' arena), the sensors
through a ``Sensing`` callable, and time through a clock and a ``Scheduler`` (the
discrete-event queue of ``simulate`` and the arena, or real time in a worker).

The loop keeps the route over the open tasks of every VV aboard with its planner, flies to
the next task, reads the sensors there for every task within tolerance and completes those
tasks (which resumes their VVs). It asks the planner again when it arrives and, when the
planner ``retargets``, whenever work is added in flight. With nothing left to do it waits in
the air at its standby position for a while (planners that ``stand_by``) and then flies home
and lands. Every flight keeps clear of the provider's no-fly zones (``fleet.airspace``): where
a straight leg would cross one, the vehicle flies the way around it, turn point by turn point,
and the planner weighs the way's length. A battery that cannot take the vehicle to its next
task and home with its reserve sends it home to recharge, out of service meanwhile. An
operator's command (``OperatorCommand``: return home now, land now), which the store hands
over once, is obeyed at once; the store has the RV out of service already, so the loop sends
it nowhere else until an operator returns it to service.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from shapely.geometry import Polygon

from fleet.airspace import NO_ZONES, Airspace
from fleet.driving import LINK_LOST, Driver, DriverError, LinkDown, SensorFailure
from fleet.geo import Position, within_m
from vvm_worker.planning import Planner, PlanTask, standby_position

logger = logging.getLogger("cpcc.executor")

# The vehicle's status, as the store keeps it (the values of fleet.models.VehicleStatus).
ACTIVE = "active"
MAINTENANCE = "maintenance"
CHARGING = "charging"
OFFLINE = "offline"  # in service, but it cannot be flown (its link, its autopilot)

# An operator's commands (the values of fleet.models.VehicleCommand).
RETURN_HOME = "return_home"
LAND = "land"
PHASE_LANDING_DOWN = "landing"  # a driver's phase while it descends to land (Driver.phase_at)

# A vehicle at its target serves every open task within the task's tolerance plus this much
# (floating-point slack of the kinematics).
REACH_SLACK_M = 1e-3
# A vehicle not there at its estimated arrival is looked at this often, and sent there anew
# when this late.
ARRIVAL_POLL_S = 0.2
ARRIVAL_OVERDUE_S = 60.0
# A vehicle whose battery is measured is looked at this often while it charges.
CHARGE_POLL_S = 1.0
# Altitudes of this many tasks served last place the standby position.
RECENT_TASKS = 20
# A turn point of a way around a no-fly zone is passed within this (ArduCopter's default
# waypoint radius).
TURN_TOLERANCE_M = 2.0
# Why a task no way reaches fails, in a customer's words.
NO_WAY = "no way around the no-fly zones reaches the task's position"


@dataclass(frozen=True)
class LoopTask:
    """An open task of the RV as the loop sees it. ``vv`` and ``group`` are the store's: the
    VV that asked for it and the request it belongs to (an executeAll batch is one);
    ``weight``: its customer's service class weight (1 without a class)."""

    id: int
    position: Position
    tolerance_m: float
    requested_s: float
    sensors: tuple[str, ...] = ()
    vv: Any = None
    group: str | None = None
    weight: float = 1.0

    def as_plan_task(self) -> PlanTask:
        return PlanTask(
            self.id, self.position, self.requested_s, group=self.group, weight=self.weight
        )


@dataclass(frozen=True)
class OperatorCommand:
    """An operator's command for the RV (RETURN_HOME or LAND), and ``asked``: when it was
    given (the store's words, shown back to the operator with what the loop does)."""

    name: str
    asked: str = ""


@dataclass(frozen=True)
class VehicleState:
    """What the loop reports of its vehicle at ``t_s``."""

    t_s: float
    position: Position
    phase: str
    distance_m: float
    flight_s: float
    planner_state: Any


@dataclass(frozen=True)
class Area:
    """Where the RV may fly: its area and altitudes (the standby position lies inside)."""

    polygon: Polygon
    min_altitude_m: float
    max_altitude_m: float


class Store(Protocol):
    """The RV's work and status as the loop reads and changes them."""

    def open_tasks(self) -> Sequence[LoopTask]:
        """The RV's open tasks, oldest request first (requested_s, id)."""
        ...

    def status(self) -> str:
        """The RV's status (ACTIVE, MAINTENANCE, CHARGING, ...)."""
        ...

    def set_status(self, status: str, *, expected: str | None = None, reason: str = "") -> None:
        """Change the RV's status, for ``reason`` (only from ``expected`` when given)."""
        ...

    def take_command(self) -> OperatorCommand | None:
        """An operator's command that waits for the RV, handed over once (None: none
        waits). Read with the status: asking costs nothing until the status changes."""
        ...

    def complete(self, task: LoopTask, readings: list[dict[str, Any]], now_s: float) -> None:
        """The task was served with these readings (its VV resumes)."""
        ...

    def fail(self, task: LoopTask, reason: str, now_s: float) -> None:
        """The vehicle was there but took no reading (``reason``, in a customer's words): the
        task ends with that error (its VV resumes with it)."""
        ...

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        """The vehicle is here now (``moved``: somewhere else than at the last record)."""
        ...

    def area(self) -> Area: ...

    def aboard(self) -> list[dict[str, Any]]:
        """The VVs aboard, for the live map (as of the last record)."""
        ...


class Scheduler(Protocol):
    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        """Run fn when the platform clock reaches t_s."""
        ...


class PlanElsewhere(Protocol):
    def __call__(
        self,
        vehicle: str,
        planner: Planner,
        current: Position,
        tasks: list[PlanTask],
        now_s: float,
        then: Callable[[list[PlanTask]], None],
    ) -> None:
        """Have ``planner.plan(current, tasks, now_s)`` made away from the loop's thread (the
        planner's time is another core's, not the loop's), with ``planner``'s state as it is
        now, and then run ``then`` with the route, on the loop's thread, as a piece of work of
        its own (where the planner raises, that piece of work raises). Afterwards the
        planner's ``state()`` is the state after that plan."""
        ...


class Sensing(Protocol):
    def __call__(
        self, task: LoopTask, position: Position, now_s: float, battery: float | None
    ) -> list[dict[str, Any]]:
        """The readings of the task's sensors taken here and now."""
        ...


def no_sensors(
    task: LoopTask, position: Position, now_s: float, battery: float | None
) -> list[dict[str, Any]]:
    """Sensing for a loop whose readings nobody reads (the arena)."""
    return []


@dataclass(frozen=True)
class LoopConfig:
    """How the loop treats the battery and idle time (seconds of flight, at the driver's
    speed)."""

    battery_s: float | None = None
    reserve: float = 0.0  # a fraction of battery_s never planned away
    recharge_s: float = 0.0
    # A measured battery (a real vehicle's) is charged when it reports this much: a swap is
    # seen at once, and a battery still low keeps the vehicle out of service.
    resume: float = 0.9
    standby_s: float = 0.0
    live: bool = False  # someone watches the map: keep the route up to date at every change
    # A wake-up that finds the vehicle at its target with the arrival due (the leg flown, its
    # arrival not taken up yet) leaves the plan to that arrival, which plans anyway once the
    # tasks there are served: the RV workers, where with fast flights most wake-ups find it
    # so. False (``simulate`` and the arena): it plans at once, as their event order has it.
    wake_defers_to_arrival: bool = False


class ControlLoop:
    """The control loop of one RV."""

    def __init__(
        self,
        *,
        name: str,
        driver: Driver,
        planner: Planner,
        store: Store,
        scheduler: Scheduler,
        clock: Callable[[], float],
        sensing: Sensing = no_sensors,
        config: LoopConfig = LoopConfig(),
        plan_timer: Callable[[], float] | None = None,
        airspace: Airspace = NO_ZONES,
        on_estimates: Callable[[dict[Any, float]], None] | None = None,
        plan_elsewhere: PlanElsewhere | None = None,
    ) -> None:
        self.name = name
        self.driver = driver
        self.planner = planner
        self.store = store
        self.scheduler = scheduler
        self.clock = clock
        self.sensing = sensing
        self.config = config
        self.airspace = airspace
        # Told at each plan when the vehicle expects to reach each VV's next task (`_estimate`).
        self.on_estimates = on_estimates
        # Endurance kept for the unexpected: never planned away (seconds of flight).
        self.reserve_s = config.reserve * config.battery_s if config.battery_s else 0.0
        self.standby_until: float | None = None  # waiting in the air for work until then
        self.recent_alts: list[float] = []
        self._charged_at: float | None = None  # when a charge under way is done
        self.target: int | None = None  # the task the vehicle is flying to
        # The leg flown now: where it ends, within what, and when it is estimated there.
        self._leg: tuple[Position, float, float] | None = None
        # The points still to fly through after this leg (around no-fly zones), the last one
        # the target's (or above home's, then the landing follows), and the target's
        # tolerance.
        self._via: list[Position] = []
        self._tolerance_m = 0.0
        self._homing = False  # flying the way home: it lands at the end
        self.returning = False
        # An operator's "land now" under way: when the touchdown is due (None: none).
        self._landing_due: float | None = None
        self.command: OperatorCommand | None = None  # the operator's last, as obeyed
        self._token = 0  # invalidates the arrival of a leg that was replaced
        # What the live map shows between two plans: the status and the open tasks in the
        # order the vehicle means to serve them.
        self.status = ACTIVE
        self.route: list[PlanTask] = []
        self._last_state: VehicleState | None = None  # what record_state got last
        self._changes = 0  # changes announced by `changed`
        self._planned_at_change = 0  # how many of them the last plan had seen
        # Wall time of each planner call, when `plan_timer` is given (the arena's sweeps).
        self.plan_timer = plan_timer
        self.planning_s: list[float] = []
        # Where a retargeting planner's plans are made (None: here, at once; see PlanElsewhere)
        # and which request is the latest: an answer to an older one is dropped.
        self.plan_elsewhere = plan_elsewhere if planner.retargets else None
        self._plan_request = 0

    def _log(self) -> dict[str, Any]:
        return {"vehicle": self.name}

    # --- events ------------------------------------------------------------------------------

    def wake(self) -> None:
        """The vehicle's tasks or status changed: re-plan, unless its target still stands and
        its planner keeps targets until it gets there."""
        now = self.clock()
        if self._obey_command(now):
            return
        if (
            self.config.wake_defers_to_arrival
            and self.target is not None
            and self._leg
            and not self._via
        ):
            position, tolerance_m, due_s = self._leg
            if due_s <= now and self.driver.has_arrived(position, tolerance_m, now):
                return  # the arrival, due, plans with the change (see LoopConfig)
        if not self.planner.retargets and self.target is not None:
            tasks = self.store.open_tasks()
            if any(t.id == self.target for t in tasks):
                if self.config.live:  # the map shows new work at once
                    here = self.driver.position_at(now)
                    plan = [t.as_plan_task() for t in tasks]
                    self.route = self.planner.route(here, plan, now)
                    self._estimate(tasks)  # and its VVs when it gets to their tasks
                return
        self._plan(now)

    def changed(self) -> Callable[[], None]:
        """The vehicle's tasks or status were just changed: the wake-up to run for it, which
        does nothing if the loop has planned in the meantime (it saw the change then): a VV
        resumed on this RV while it serves its stop needs no second plan."""
        self._changes += 1
        seen = self._changes

        def wake_unless_planned() -> None:
            if self._planned_at_change < seen:
                self.wake()

        return wake_unless_planned

    def _arrive(self, token: int, target: Position, tolerance_m: float, due_s: float) -> None:
        if token != self._token:
            return
        now = self.clock()
        if not self.driver.has_arrived(target, tolerance_m, now):
            # A real vehicle is there when its telemetry says so, not when the estimate said:
            # look again shortly, and fly there anew if it is far overdue (a gust, a fence).
            if now - due_s > ARRIVAL_OVERDUE_S:
                logger.warning("arrival overdue: flying there again", extra=self._log())
                self.target = None  # not "still the best target": it is sent there anew
                self._homing = False
                self._plan(now)
            else:
                self.scheduler.call_at(
                    now + ARRIVAL_POLL_S, lambda: self._arrive(token, target, tolerance_m, due_s)
                )
            return
        if self._via:  # a turn point on the way around a no-fly zone: on to the next
            self._record(now)
            self._next_leg(token, now)
            return
        if self._homing:
            self._homing = False
            self._record(now)
            self._land(now, token)
            return
        self.target = None
        # The end of the leg is on the track of the VVs aboard, before any of them leaves, and
        # the store says the vehicle is here: a VV migrating off it now records this position.
        self._record(now)
        here = self.driver.position_at(now)
        served = [
            t
            for t in self.store.open_tasks()
            if within_m(here, t.position, t.tolerance_m + REACH_SLACK_M)
        ]
        battery = self.battery_fraction(now)
        if served:
            logger.info(
                "%s arrived: %d task(s) to serve",
                self.name,
                len(served),
                extra={**self._log(), "tasks": ",".join(str(t.id) for t in served)},
            )
        for task in served:
            self.recent_alts = [*self.recent_alts[1 - RECENT_TASKS :], task.position.alt]
            try:
                readings = self.sensing(task, here, now, battery)
            except SensorFailure as failure:
                logger.warning("reading failed: %s", failure, extra=self._log())
                self.store.fail(task, failure.reason, now)
            else:
                self.store.complete(task, readings, now)
        self._plan(now)

    def _landed(self, token: int, due_s: float) -> None:
        if token != self._token:
            return
        now = self.clock()
        if not self.driver.is_landed_at(now):
            if now - due_s > ARRIVAL_OVERDUE_S:
                logger.warning("landing overdue: returning again", extra=self._log())
                self._plan(now)
            else:
                self.scheduler.call_at(now + ARRIVAL_POLL_S, lambda: self._landed(token, due_s))
            return
        self.returning = False
        self._landing_due = None
        logger.info("%s landed", self.name, extra=self._log())
        if self.status == CHARGING:
            self._charge(now)
        self._record(now)

    # --- the battery ---------------------------------------------------------------------------

    def _within_battery(self, now: float, way: list[Position]) -> bool:
        """Whether the vehicle can fly ``way`` and home from its end with its reserve left."""
        remaining = self.driver.battery_remaining_s(now)
        if remaining is None:
            return True
        need = self._way_s(way, now) + self._time_home_s(way[-1])
        if remaining - need >= self.reserve_s:
            return True
        if self.driver.is_landed_at(now) and remaining >= (self.config.battery_s or 0.0):
            # Full, and still too far: no charge helps; the mapper does not know the range.
            logger.warning("task beyond the battery's range", extra=self._log())
            return True
        return False

    def _run_low(self) -> None:
        """Hand the work over and go home to recharge: the VVs aboard move to RVs that can
        serve them (or wait), and this RV takes no work until it is full again."""
        logger.info(
            "%s: battery too low for the next task: home to recharge",
            self.name,
            extra={**self._log(), "battery": self.battery_fraction(self.clock())},
        )
        self.store.set_status(CHARGING, reason="battery too low for the next task")
        self.status = CHARGING

    def _charge(self, now: float) -> None:
        if self._charged_at is not None:
            return
        if self.driver.measures_battery:
            self._charged_at = now  # under way until the vehicle reports a charged battery
            logger.info(
                "%s: waiting for a charged battery (%s, back in service from %.0f %%)",
                self.name,
                _percent(self.battery_fraction(now)),
                100 * self.config.resume,
                extra=self._log(),
            )
            self.scheduler.call_at(now + CHARGE_POLL_S, self._charge_check)
            return
        self._charged_at = self.driver.recharge(now, self.config.recharge_s)
        self.scheduler.call_at(self._charged_at, self._charged)

    def _charge_check(self) -> None:
        """A measured battery: back into service when it reports ``config.resume`` or more
        (charged, or swapped), else look again; nothing more once the RV left ``charging``
        (a person decided otherwise)."""
        now = self.clock()
        if self.store.status() != CHARGING:
            self._charged_at = None
            return
        fraction = self.battery_fraction(now)
        if fraction is None or fraction >= self.config.resume:
            self._charged()
            return
        self.scheduler.call_at(now + CHARGE_POLL_S, self._charge_check)

    def set_battery(self, battery_s: float | None) -> None:
        """The vehicle's endurance was reconfigured: plan with it from now on."""
        self.config = dataclasses.replace(self.config, battery_s=battery_s)
        self.reserve_s = self.config.reserve * battery_s if battery_s else 0.0

    def _charged(self) -> None:
        self._charged_at = None
        logger.info("%s charged", self.name, extra=self._log())
        # Back into service, unless the provider decided otherwise meanwhile.
        self.store.set_status(ACTIVE, expected=CHARGING, reason="charged")
        self.wake()

    def battery_fraction(self, now: float) -> float | None:
        remaining = self.driver.battery_remaining_s(now)
        if remaining is None or not self.config.battery_s:
            return None
        return max(0.0, min(1.0, remaining / self.config.battery_s))

    # --- planning ------------------------------------------------------------------------------

    def _plan(self, now: float) -> None:
        self._plan_request += 1  # whatever was asked for before is out of date now
        if self._obey_command(now):
            return
        self._planned_at_change = self._changes
        self.status = self.store.status()
        tasks = list(self.store.open_tasks()) if self.status == ACTIVE else []
        if tasks and self.plan_elsewhere is not None:
            request = self._plan_request
            here = self.driver.position_at(now)
            plan = [t.as_plan_task() for t in tasks]
            self.plan_elsewhere(
                self.name,
                self.planner,
                here,
                plan,
                now,
                lambda route: self._planned(request, tasks, route),
            )
            return
        route: list[PlanTask] = []
        if tasks:
            here = self.driver.position_at(now)
            started = self.plan_timer() if self.plan_timer is not None else 0.0
            route = self.planner.plan(here, [t.as_plan_task() for t in tasks], now)
            if self.plan_timer is not None:
                self.planning_s.append(self.plan_timer() - started)
        self._follow(now, tasks, route)

    def _planned(self, request: int, tasks: list[LoopTask], route: list[PlanTask]) -> None:
        """A plan made elsewhere is back: follow it, unless the loop has asked for a newer one
        (or obeyed a command) meanwhile."""
        if request == self._plan_request:
            self._follow(self.clock(), tasks, route)

    def _follow(self, now: float, tasks: list[LoopTask], route: list[PlanTask]) -> None:
        """Fly the plan ``route`` over ``tasks``: to its first task, as far as the battery
        allows; with none, stand by, go home or land."""
        here = self.driver.position_at(now)
        choice: LoopTask | None = None
        way: list[Position] | None = None  # to the choice, round the no-fly zones
        self.route = route
        if route:
            first = route[0].id
            choice = next((t for t in tasks if t.id == first), None)
            if choice is not None:
                way = self.airspace.way(here, choice.position)
                if not self._within_battery(now, way or [choice.position]):
                    self._run_low()
                    choice, self.route = None, []
        if self.status == CHARGING and self.driver.is_landed_at(now):
            self._charge(now)
        if choice is not None and choice.id == self.target and not self.returning:
            self._estimate(tasks)  # (others' tasks may have joined the route)
            self._record(now)  # still the best target: fly on
            return
        self._token += 1
        token = self._token
        if choice is not None:
            if way is None:
                logger.warning("task walled in by no-fly zones", extra=self._log())
                self.target = None
                self.store.fail(choice, NO_WAY, now)
                self._plan(now)
                return
            self.target = choice.id
            self._leg = None
            self.returning = False
            self._homing = False
            self._landing_due = None
            self.standby_until = None
            self._via, self._tolerance_m = way, choice.tolerance_m
            self._next_leg(token, now)
            self._estimate(tasks)
        else:
            self.target = None
            if self._landing_due is not None:
                self._keep_landing(now, token)  # an operator's "land now" holds
            elif not self.driver.is_landed_at(now) and not self._stand_by(now, token):
                self._go_home(now, token)
        self._record(now)

    # --- an operator's commands --------------------------------------------------------------

    def _obey_command(self, now: float) -> bool:
        """Obey the operator's command that waits, if any (True: one was obeyed). The RV is
        out of service (the store put it there with the command): nothing else is planned.
        RETURN_HOME flies home at once, around the no-fly zones (a MAVLink autopilot gets its
        RTL for the last leg), and takes off first where an earlier "land now" left it;
        LAND lands where the vehicle is."""
        command = self.store.take_command()
        if command is None:
            return False
        logger.warning(
            "%s: the operator's command: %s",
            self.name,
            command.name,
            extra={**self._log(), "command": command.name},
        )
        self.command = command
        self._planned_at_change = self._changes
        self.status = self.store.status()
        self._token += 1
        token = self._token
        self.target, self.route, self._leg, self._via = None, [], None, []
        self.standby_until = None
        self._homing = False
        if command.name == LAND:
            self.returning = False
            self._land_here(now, token)
        else:
            self._landing_due = None
            self.returning = False  # (logged anew: "returning home")
            if self.driver.is_landed_at(now) and not within_m(
                self.driver.position_at(now), self.driver.depot, TURN_TOLERANCE_M
            ):
                self._take_off_home(now, token)
            else:
                self._go_home(now, token)
        self._record(now)
        return True

    def _land_here(self, now: float, token: int) -> None:
        """Land where the vehicle is, and watch for the touchdown."""
        try:
            due = self.driver.land(now)
        except DriverError as exc:
            self._landing_due = now  # the operator's word stands: tried again at each plan
            self._failed(exc)
            return
        self._landing_due = due
        self.scheduler.call_at(self._first_look(now, due), lambda: self._landed(token, due))

    def _keep_landing(self, now: float, token: int) -> None:
        """A plan during an operator's landing: the landing goes on (watched anew, its old
        watch superseded by the plan); one that did not start (the link was down) is asked
        again."""
        due = self._landing_due
        if due is None or self.driver.phase_at(now) != PHASE_LANDING_DOWN:
            self._land_here(now, token)
            return
        self.scheduler.call_at(self._first_look(now, due), lambda: self._landed(token, due))

    def _take_off_home(self, now: float, token: int) -> None:
        """Landed away from home (an operator's "land now"): up to the middle of the
        altitudes it may fly, home around the no-fly zones, and down. A vehicle that does not
        fly (ground, surface, underwater: its altitudes end at 0 m) goes home on the ground or
        the surface: a sub that surfaced does not dive again to come home."""
        area = self.store.area()
        up = (area.min_altitude_m + area.max_altitude_m) / 2
        if area.max_altitude_m <= 0.0:
            up = area.max_altitude_m
        here = self.driver.position_at(now)
        way = self.airspace.way(here.with_alt(up), self.driver.depot.with_alt(up))
        if way is None:
            logger.warning("home walled in by no-fly zones: flying straight", extra=self._log())
            way = [self.driver.depot.with_alt(up)]
        logger.info("%s returning home", self.name, extra=self._log())
        self.returning = True
        self._homing = True
        self._via = list(way)
        self._next_leg(token, now)

    def _estimate(self, tasks: Sequence[LoopTask]) -> None:
        """Tell ``on_estimates`` when the vehicle expects to reach each VV's next task on its
        route (platform clock, by VV: the store's ``LoopTask.vv``): the target at the end of
        the way flown now, then each other task of the route one straight leg after the one
        before it."""
        if self.on_estimates is None or self.target is None or self._leg is None:
            return
        vv_of = {t.id: t.vv for t in tasks}
        here, _, t_s = self._leg
        for point in self._via:
            t_s += self.driver.leg_s(here, point)
            here = point
        etas: dict[Any, float] = {}
        if vv_of.get(self.target) is not None:
            etas[vv_of[self.target]] = t_s
        for task in self.route:
            if task.id == self.target:
                continue
            t_s += self.driver.leg_s(here, task.position)
            here = task.position
            vv = vv_of.get(task.id)
            if vv is not None:
                etas.setdefault(vv, t_s)
        self.on_estimates(etas)

    def _next_leg(self, token: int, now: float) -> None:
        """Fly the next leg of the way (``_via``): to a turn point, or to the way's end."""
        point = self._via.pop(0)
        tolerance_m = TURN_TOLERANCE_M if self._via or self._homing else self._tolerance_m
        if self.driver.is_landed_at(now):
            logger.info("%s taking off", self.name, extra=self._log())
        try:
            arrival = self.driver.fly_to(point, now)
        except DriverError as exc:
            self._failed(exc)
            return
        self._leg = (point, tolerance_m, arrival)
        self.scheduler.call_at(
            self._first_look(now, arrival), lambda: self._arrive(token, point, tolerance_m, arrival)
        )

    def _first_look(self, now: float, due_s: float) -> float:
        """When to look first whether the vehicle got there: at the estimate, or soon for a
        vehicle that reports where it is (a real one may be quicker than estimated)."""
        if self.driver.reports_arrival:
            return min(due_s, now + ARRIVAL_POLL_S)
        return due_s

    def _go_home(self, now: float, token: int) -> None:
        if not self.returning:
            logger.info("%s returning home", self.name, extra=self._log())
        self.returning = True
        self.standby_until = None
        self._via = []
        if not self.driver.is_landed_at(now):
            way = self._way_home(self.driver.position_at(now))
            if way is None:
                logger.warning("home walled in by no-fly zones: flying straight", extra=self._log())
            elif len(way) > 1:  # around the zones to the last turn point, then home
                self._homing = True
                self._via = way[:-1]
                self._next_leg(token, now)
                return
        self._land(now, token)

    def _land(self, now: float, token: int) -> None:
        try:
            landing = self.driver.return_to_depot(now)
        except DriverError as exc:
            self._failed(exc)
            return
        self.scheduler.call_at(self._first_look(now, landing), lambda: self._landed(token, landing))

    def _way_home(self, start: Position) -> list[Position] | None:
        """The way from ``start`` to above the depot at its altitude (``Airspace.way``)."""
        return self.airspace.way(start, self.driver.depot.with_alt(start.alt))

    def _way_s(self, way: list[Position], now: float) -> float:
        """Estimated seconds to fly ``way`` from where the vehicle is now."""
        first = self.driver.time_to_s(way[0], now)
        return first + sum(self.driver.leg_s(a, b) for a, b in itertools.pairwise(way))

    def _time_home_s(self, start: Position) -> float:
        """Estimated seconds to return home from ``start``, around the no-fly zones."""
        way = self._way_home(start) or [start]
        turns = [start, *way[:-1]]
        around = sum(self.driver.leg_s(a, b) for a, b in itertools.pairwise(turns))
        return around + self.driver.time_home_s(turns[-1])

    def _stand_by(self, now: float, token: int) -> bool:
        """Wait in the air at the standby position, if the planner wants it and the battery
        allows it (there, a while, and home with the reserve left). False: fly home."""
        if (
            not self.planner.stands_by
            or self.config.standby_s <= 0
            or self.status != ACTIVE
            or self.returning
        ):
            return False
        if self.standby_until is not None:
            if now >= self.standby_until:
                return False
            self.scheduler.call_at(self.standby_until, lambda: self._standby_over(token))
            return True  # already waiting (or on the way there): keep its deadline
        area = self.store.area()
        spot = standby_position(
            area.polygon,
            self.recent_alts,
            min_altitude_m=area.min_altitude_m,
            max_altitude_m=area.max_altitude_m,
        )
        if self.airspace.way(self.driver.position_at(now), spot) != [spot]:
            return False  # no straight way there (a no-fly zone): home instead
        wait_s = self.config.standby_s
        remaining = self.driver.battery_remaining_s(now)
        if remaining is not None:
            spare = remaining - self.reserve_s - self.driver.time_to_s(spot, now)
            wait_s = min(wait_s, spare - self._time_home_s(spot))
            if wait_s <= 0:
                return False
        self._via = []
        try:
            there = self.driver.fly_to(spot, now)
        except DriverError as exc:
            self._failed(exc)
            return True
        self.standby_until = there + wait_s
        if self.driver.reports_arrival:
            # A real vehicle waits its standby time from when its telemetry says it is there,
            # not from the estimate (one quicker than its specification would wait longer).
            self.scheduler.call_at(
                self._first_look(now, there),
                lambda: self._at_standby(token, spot, there, wait_s),
            )
        else:
            self.scheduler.call_at(self.standby_until, lambda: self._standby_over(token))
        return True

    def _at_standby(self, token: int, spot: Position, due_s: float, wait_s: float) -> None:
        """Whether the vehicle is at its standby position yet: from then it waits ``wait_s``
        (from now, if it is far overdue: it waits where it is, then goes home)."""
        if token != self._token:
            return
        now = self.clock()
        if not self.driver.has_arrived(spot, TURN_TOLERANCE_M, now) and (
            now - due_s <= ARRIVAL_OVERDUE_S
        ):
            self.scheduler.call_at(
                now + ARRIVAL_POLL_S, lambda: self._at_standby(token, spot, due_s, wait_s)
            )
            return
        self.standby_until = now + wait_s
        self.scheduler.call_at(self.standby_until, lambda: self._standby_over(token))

    def _standby_over(self, token: int) -> None:
        if token != self._token:
            return
        now = self.clock()
        if self.standby_until is not None and now < self.standby_until:
            return  # its wait started later than estimated: the call at its end is scheduled
        self._token += 1
        self._go_home(now, self._token)
        self._record(now)

    def _failed(self, exc: DriverError) -> None:
        """The vehicle cannot be flown (its link, its autopilot refused, a pilot took over):
        it goes offline so that its VVs move on (a person's decision, maintenance, stays as
        it is); the operator returns it to service (or its worker, once the link is back).
        A link that is down gives the link watch's reason, whichever of the two saw it first."""
        logger.error("vehicle %s out of service: %s", self.name, exc, extra=self._log())
        self.target = None
        reason = LINK_LOST if isinstance(exc, LinkDown) else str(exc)
        self.store.set_status(OFFLINE, expected=ACTIVE, reason=reason)
        self.status = self.store.status()

    # --- what the vehicle reports -------------------------------------------------------------

    def live_state(self, now: float) -> dict[str, Any]:
        """The RV as the live map shows it now (positions as [lat, lng])."""
        here = self.driver.position_at(now)
        ahead: list[Position] = []
        if not self.returning:
            # The turn points still ahead on the way to the target, then the tasks.
            if self._via and self._leg is not None:
                ahead += [self._leg[0], *self._via[:-1]]
            ahead += [t.position for t in self.route]
        return {
            "lat": here.lat,
            "lng": here.lng,
            "alt": here.alt,
            "phase": self.driver.phase_at(now),
            "status": self.status,
            "battery": self.battery_fraction(now),
            "vvs": self.store.aboard(),
            "route": [[here.lat, here.lng]] + [[p.lat, p.lng] for p in ahead],
            "activity": self._activity(now),
            "next_task": self._next_task(now),
            "command": None if self.command is None else dataclasses.asdict(self.command),
        }

    def _activity(self, now: float) -> str:
        """What the vehicle is doing, in an operator's words."""
        landed = self.driver.is_landed_at(now)
        if self._landing_due is not None and not landed:
            return "landing here"
        if self.returning and not landed:
            return "returning home"
        if self.target is not None:
            return "flying to a task"
        if self.standby_until is not None and not landed:
            return "standing by"
        if self._charged_at is not None and landed:
            return "charging"
        return "landed" if landed else "hovering"

    def _next_task(self, now: float) -> dict[str, Any] | None:
        """The task the vehicle flies to (its VV, where, seconds to get there by the
        estimate), or None."""
        if self.target is None or self.returning:
            return None
        task = next((t for t in self.store.open_tasks() if t.id == self.target), None)
        if task is None:
            return None
        way = [task.position] if not self._via else [*self._via]
        leg_end = self._leg[0] if self._leg is not None else task.position
        eta_s = self.driver.time_to_s(leg_end, now)
        eta_s += sum(self.driver.leg_s(a, b) for a, b in itertools.pairwise([leg_end, *way]))
        p = task.position
        return {
            "id": task.id,
            "vv": None if task.vv is None else str(task.vv),
            "lat": p.lat,
            "lng": p.lng,
            "alt": p.alt,
            "eta_s": round(max(0.0, eta_s)),
        }

    @property
    def last_state(self) -> VehicleState | None:
        """What the store was told last (it says so, written or about to be)."""
        return self._last_state

    def _record(self, now: float) -> None:
        state = VehicleState(
            t_s=now,
            position=self.driver.position_at(now),
            phase=self.driver.phase_at(now),
            distance_m=self.driver.distance_m(now),
            flight_s=self.driver.flight_s(now),
            planner_state=self.planner.state(),
        )
        last = self._last_state
        moved = last is None or state.position != last.position
        if last is not None and not moved and _same_report(state, last):
            return  # the store says all this already (a second look at the same moment)
        self.store.record_state(state, moved=moved)
        self._last_state = state  # only once recorded: work redone after an outage records it


def _percent(fraction: float | None) -> str:
    return "not reported" if fraction is None else f"{100 * fraction:.0f} %"


def _same_report(a: VehicleState, b: VehicleState) -> bool:
    return (a.position, a.phase, a.distance_m, a.flight_s, a.planner_state) == (
        b.position,
        b.phase,
        b.distance_m,
        b.flight_s,
        b.planner_state,
    )
