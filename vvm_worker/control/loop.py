"""``ControlLoop``: the control loop of one RV, its events (a wake-up, an arrival, a landing)
on its parts (vvm_worker/control/__init__.py says what it does)."""

from __future__ import annotations

import logging
from collections.abc import Callable

from fleet.driving import SensorFailure
from fleet.geo import Position, within_m
from vvm_worker.control.planning import Planning
from vvm_worker.control.types import (
    ARRIVAL_OVERDUE_S,
    ARRIVAL_POLL_S,
    CHARGING,
    REACH_SLACK_M,
    RECENT_TASKS,
)
from vvm_worker.planning import PlanTask

logger = logging.getLogger("cpcc.executor")


class ControlLoop(Planning):
    """The control loop of one RV."""

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
                plan = [t.as_plan_task() for t in tasks]
                if self._late_unless_turning(now, plan):
                    self._plan(now)
                    return
                if self.config.live:  # the map shows new work at once
                    here = self.driver.position_at(now)
                    self.route = self.planner.route(here, plan, now)
                    self._estimate(tasks)  # and its VVs when it gets to their tasks
                return
        self._plan(now)

    def _late_unless_turning(self, now: float, plan: list[PlanTask]) -> bool:
        """Whether a task of ``plan`` (the open tasks) whose deadline is earlier than the
        target's would be late unless the vehicle turned to it now (a planner that keeps its
        target is overruled then)."""
        if all(task.deadline_s is None for task in plan):
            return False
        here = self.driver.position_at(now)
        kept = [t for t in plan if t.id == self.target]
        kept += [t for t in plan if t.id != self.target]
        route = self._in_time(here, now, kept)
        return bool(route) and route[0].id != self.target

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
                self._watch_flight(now)  # (a real vehicle's altitude, between reports)
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
        self._serve_here(now)
        self._plan(now)

    def _serve_here(self, now: float) -> None:
        """Read the sensors for every open task within reach of where the vehicle is, and
        answer each (with its readings, or with why they failed)."""
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
        self._touched_down(now)  # the flight's end goes with the report below
        if self.status == CHARGING:
            self._charge(now)
        self._record(now)
