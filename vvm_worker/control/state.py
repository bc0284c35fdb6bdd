"""The control loop's state: what it is given and keeps, and what it reports of the vehicle
(``live_state``, the store's reports)."""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fleet.airspace import NO_ZONES, Airspace
from fleet.driving import Driver
from fleet.geo import Position, ground_distance_m
from vvm_worker.control.types import (
    ACTIVE,
    BY_OPERATOR,
    FAILSAFE,
    HOME_RADIUS_M,
    LANDED_ELSEWHERE,
    LANDED_HOME,
    KeepsFlightLog,
    Landing,
    LoopConfig,
    MeasuredBattery,
    OperatorCommand,
    PlanElsewhere,
    ReportsTakeOver,
    Scheduler,
    Sensing,
    Store,
    VehicleState,
    no_sensors,
)
from vvm_worker.planning import Planner, PlanTask

logger = logging.getLogger("cpcc.executor")

DEFAULT_CONFIG = LoopConfig()  # no battery, no standby


@dataclass
class Flight:
    """A flight under way, as the loop keeps it from the take-off it commanded to the end it
    reports (``Landing``): the take-off's time and battery (percent), the highest altitude
    seen, whether the vehicle was seen off the ground yet, whether an operator's command
    took over the flight, and whether a pilot or a failsafe did."""

    took_off_s: float
    flight_s_start: float
    battery_start_pct: float | None
    max_alt: float
    airborne: bool = False
    commanded: bool = False
    taken_over: bool = False
    track: list[tuple[float, float, float, float, float | None]] = field(default_factory=list)

    def keep(self, t_s: float, here: Position, battery_pct: float | None) -> None:
        """A point of the track: where the vehicle is at a report (unless it has not moved)."""
        if not self.track or self.track[-1][1:4] != (here.lat, here.lng, here.alt):
            self.track.append((t_s, here.lat, here.lng, here.alt, battery_pct))


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
        # The flight under way since a take-off the loop commanded (None: on the ground, or
        # in the air without one: a vehicle that started there), and the end of the last one,
        # until a report says so.
        self._flight: Flight | None = None
        self._landing: Landing | None = None

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

    def battery_pct(self, now: float) -> float | None:
        """The battery's charge in percent for the flight records: what the vehicle reports
        (a MAVLink autopilot's SYS_STATUS), else the endurance left over the configured one
        (a simulated vehicle with ``battery_s``), else None."""
        fraction: float | None = None
        if isinstance(self.driver, MeasuredBattery):
            fraction = self.driver.battery_fraction()
        if fraction is None:
            fraction = self.battery_fraction(now)
        return None if fraction is None else round(100 * fraction, 1)

    def _took_off(self, now: float) -> None:
        """The loop flew the vehicle off the ground now: a flight starts, reported with the
        next report; one still open whose vehicle was seen in the air ended unseen first (it
        landed while the loop looked elsewhere). A second take-off command before the vehicle
        is seen in the air (a real one's telemetry lags) is the same flight."""
        flight = self._flight
        if flight is not None:
            self._watch_flight(now)
            if not flight.airborne:
                return
            self._touched_down(now)
        self._took_off_s = now
        if isinstance(self.driver, KeepsFlightLog):
            self.driver.flight_log.start()  # (one left open by a flight never seen to end: gone)
        here, battery_pct = self.driver.position_at(now), self.battery_pct(now)
        self._flight = Flight(now, self.driver.flight_s(now), battery_pct, here.alt)
        self._flight.keep(now, here, battery_pct)

    def _watch_flight(self, now: float) -> None:
        """What a look at the vehicle in flight keeps: the highest altitude, whether it is off
        the ground yet, whether a pilot or a failsafe took it over."""
        flight = self._flight
        if flight is None:
            return
        flight.max_alt = max(flight.max_alt, self.driver.position_at(now).alt)
        if not flight.airborne and (
            self.driver.flight_s(now) > flight.flight_s_start or not self.driver.is_landed_at(now)
        ):
            flight.airborne = True  # (it flew since: a landing now is this flight's end)
        if isinstance(self.driver, ReportsTakeOver) and self.driver.took_over is not None:
            flight.taken_over = True

    def _touched_down(self, now: float) -> None:
        """The vehicle is on the ground: the flight under way (if any) ended, by a failsafe
        or a pilot that took it over, by an operator's command, or at home (within
        HOME_RADIUS_M of its depot) or elsewhere."""
        flight = self._flight
        if flight is None:
            return
        self._watch_flight(now)
        if flight.taken_over:
            how = FAILSAFE
        elif flight.commanded:
            how = BY_OPERATOR
        elif ground_distance_m(self.driver.position_at(now), self.driver.depot) <= HOME_RADIUS_M:
            how = LANDED_HOME
        else:
            how = LANDED_ELSEWHERE
        self._flight_over(now, how)

    def _flight_over(self, now: float, how: str) -> None:
        """The flight under way ended now, ``how``: reported with the next report."""
        flight, self._flight = self._flight, None
        if flight is None:
            return
        self._watch_flight(now)
        battery_pct = self.battery_pct(now)
        flight.keep(now, self.driver.position_at(now), battery_pct)
        log = self.driver.flight_log.finish() if isinstance(self.driver, KeepsFlightLog) else None
        self._landing = Landing(
            took_off_s=flight.took_off_s,
            t_s=now,
            how=how,
            distance_m=self.driver.distance_m(now),
            flight_s=self.driver.flight_s(now),
            max_alt_m=max(0.0, flight.max_alt - self.driver.depot.alt),
            battery_start_pct=flight.battery_start_pct,
            battery_end_pct=battery_pct,
            track=tuple(flight.track),
            log=log,
        )

    def live_state(self, now: float) -> dict[str, Any]:
        """The RV as the live map shows it now (positions as [lat, lng])."""
        self._watch_flight(now)  # (the map's ticks sample a real vehicle's altitude)
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
        self._watch_flight(now)
        state = VehicleState(
            t_s=now,
            position=self.driver.position_at(now),
            phase=self.driver.phase_at(now),
            distance_m=self.driver.distance_m(now),
            flight_s=self.driver.flight_s(now),
            planner_state=self.planner.state(),
            took_off_s=self._took_off_s,
            landing=self._landing,
        )
        last = self._last_state
        moved = last is None or state.position != last.position
        if (
            last is not None
            and not moved
            and state.took_off_s is None
            and state.landing is None
            and _same_report(state, last)
        ):
            return  # the store says all this already (a second look at the same moment)
        if self._flight is not None and moved:
            self._flight.keep(now, state.position, self.battery_pct(now))
        self.store.record_state(state, moved=moved)
        # Only once recorded: work redone after an outage records it (the take-off, the
        # landing).
        self._last_state = state
        self._took_off_s = None
        self._landing = None


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
