"""The control loop's state: what it is given and keeps, and what it reports of the vehicle
(``live_state``, the store's reports)."""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Callable
from typing import Any

from fleet.airspace import NO_ZONES, Airspace
from fleet.driving import Driver
from fleet.geo import Position
from vvm_worker.control.types import (
    ACTIVE,
    LoopConfig,
    OperatorCommand,
    PlanElsewhere,
    Scheduler,
    Sensing,
    Store,
    VehicleState,
    no_sensors,
)
from vvm_worker.planning import Planner, PlanTask

logger = logging.getLogger("cpcc.executor")

DEFAULT_CONFIG = LoopConfig()  # no battery, no standby


class LoopState:
    """The state of one RV's control loop and its reports; the parts of ``ControlLoop`` build
    on it, each on the one before: ``Legs``, ``Battery``, ``Planning``, ``ControlLoop``."""

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
        config: LoopConfig = DEFAULT_CONFIG,
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
        self.plan_timer = plan_timer
        # Where a retargeting planner's plans are made (None: here, at once; see PlanElsewhere)
        # and which request is the latest: an answer to an older one is dropped.
        self.plan_elsewhere = plan_elsewhere if planner.retargets else None
        self._plan_request = 0
        self._start_on_the_ground()
        self._start_the_view()

    def _start_on_the_ground(self) -> None:
        """The flight's state as a loop starts: no leg, no target, no command."""
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
        # When the loop last flew the vehicle off the ground, until a report says so.
        self._took_off_s: float | None = None

    def _start_the_view(self) -> None:
        """What the live map and the benchmarks see of a loop that has not planned yet."""
        # What the live map shows between two plans: the status and the open tasks in the
        # order the vehicle means to serve them.
        self.status = ACTIVE
        self.route: list[PlanTask] = []
        self._last_state: VehicleState | None = None  # what record_state got last
        self._changes = 0  # changes announced by `changed`
        self._planned_at_change = 0  # how many of them the last plan had seen
        # Wall time of each planner call, when `plan_timer` is given (the arena's sweeps).
        self.planning_s: list[float] = []

    def _log(self) -> dict[str, Any]:
        return {"vehicle": self.name}

    def battery_fraction(self, now: float) -> float | None:
        remaining = self.driver.battery_remaining_s(now)
        if remaining is None or not self.config.battery_s:
            return None
        return max(0.0, min(1.0, remaining / self.config.battery_s))

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
            took_off_s=self._took_off_s,
        )
        last = self._last_state
        moved = last is None or state.position != last.position
        if (
            last is not None
            and not moved
            and state.took_off_s is None
            and _same_report(state, last)
        ):
            return  # the store says all this already (a second look at the same moment)
        self.store.record_state(state, moved=moved)
        # Only once recorded: work redone after an outage records it (and the take-off).
        self._last_state = state
        self._took_off_s = None


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
