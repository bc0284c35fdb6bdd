"""The control loop's planning: asking the planner (here or elsewhere), following its route,
and an operator's commands, obeyed before any plan."""

from __future__ import annotations

import logging

from fleet.geo import Position, within_m
from vvm_worker.control.battery import Battery
from vvm_worker.control.types import ACTIVE, CHARGING, LAND, NO_WAY, TURN_TOLERANCE_M, LoopTask
from vvm_worker.planning import PlanTask, by_deadline

logger = logging.getLogger("cpcc.executor")


class Planning(Battery):
    """Plans and an operator's commands."""

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
        route = self._in_time(here, now, route)
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

    def _in_time(self, here: Position, now: float, route: list[PlanTask]) -> list[PlanTask]:
        """The planner's route with the tasks it would reach after their deadlines moved
        forward where they are in time (``planning.by_deadline``, with this vehicle's leg
        times); the task flown to now is never put behind one whose deadline is later."""
        flying_to = None if self.returning else self.target
        return by_deadline(route, start=here, now_s=now, leg=self.driver.leg_s, flying_to=flying_to)

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
        if self._flight is not None:  # this flight ends as the operator commanded
            self._flight.commanded = True
        self._record(now)
        return True
