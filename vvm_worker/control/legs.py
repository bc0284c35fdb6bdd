"""The control loop's flying: legs to a target (around no-fly zones), home and landing, an
operator's landing, standing by; the plan's estimates."""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from typing import Any

from fleet.driving import LINK_LOST, DriverError, LinkDown
from fleet.geo import Position
from vvm_worker.control.state import LoopState
from vvm_worker.control.types import (
    ACTIVE,
    ARRIVAL_OVERDUE_S,
    ARRIVAL_POLL_S,
    FAILSAFE,
    LINK_LOST_IN_FLIGHT,
    OFFLINE,
    PHASE_LANDING_DOWN,
    TURN_TOLERANCE_M,
    LoopTask,
)
from vvm_worker.planning import standby_position

logger = logging.getLogger("cpcc.executor")


class Legs(LoopState):
    """Legs, the way home, landing, standing by."""

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
        landed = self.driver.is_landed_at(now)
        if landed:
            logger.info("%s taking off", self.name, extra=self._log())
        try:
            arrival = self.driver.fly_to(point, now)
        except DriverError as exc:
            self._failed(exc)
            return
        if landed and arrival > now:
            # It leaves the ground now (a real vehicle's telemetry may say so only later): the
            # next report carries the take-off, which the store keeps with its pilot then.
            self._took_off(now)
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
        # A flight under way ends where the platform lost the vehicle: its link, or a pilot or
        # failsafe that took it over (the vehicle may fly on; the record is the platform's).
        # Any other refusal leaves it open: the loop lands it once it is back in service.
        now = self.clock()
        self._watch_flight(now)
        if self._flight is not None and isinstance(exc, LinkDown):
            self._flight_over(now, LINK_LOST_IN_FLIGHT)
        elif self._flight is not None and self._flight.taken_over:
            self._flight_over(now, FAILSAFE)
        self.store.set_status(OFFLINE, expected=ACTIVE, reason=reason)
        self.status = self.store.status()

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

    def _arrive(self, token: int, target: Position, tolerance_m: float, due_s: float) -> None:
        """The vehicle is due at the leg's end (``ControlLoop``: it serves the tasks there)."""
        raise NotImplementedError

    def _landed(self, token: int, due_s: float) -> None:
        """The vehicle is due on the ground (``ControlLoop``)."""
        raise NotImplementedError
