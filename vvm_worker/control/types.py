"""The control loop's vocabulary: the vehicle's statuses and an operator's commands, the
tasks, reports and areas it deals in, what it is given (``Store``, ``Scheduler``, ``Sensing``,
``PlanElsewhere``) and its configuration."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from shapely.geometry import Polygon

from fleet.geo import Position
from vvm_worker.planning import Planner, PlanTask

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

# How a flight ended (the values of fleet.models.FlightEnd).
LANDED_HOME = "landed_home"
LANDED_ELSEWHERE = "landed_elsewhere"
LINK_LOST_IN_FLIGHT = "link_lost"
FAILSAFE = "failsafe"
BY_OPERATOR = "operator"
# A landing this close to the depot (on the ground) is a landing at home.
HOME_RADIUS_M = 5.0

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
    ``weight``: its customer's service class weight (1 without a class); ``deadline_s``: when
    it is to be read by (its request time plus the class's target; None: no class);
    ``service_class``: the class's id (None: no class)."""

    id: int
    position: Position
    tolerance_m: float
    requested_s: float
    sensors: tuple[str, ...] = ()
    vv: Any = None
    group: str | None = None
    weight: float = 1.0
    deadline_s: float | None = None
    service_class: int | None = None

    def as_plan_task(self) -> PlanTask:
        return PlanTask(
            self.id,
            self.position,
            self.requested_s,
            group=self.group,
            weight=self.weight,
            deadline_s=self.deadline_s,
        )


@dataclass(frozen=True)
class OperatorCommand:
    """An operator's command for the RV (RETURN_HOME or LAND), and ``asked``: when it was
    given (the store's words, shown back to the operator with what the loop does)."""

    name: str
    asked: str = ""


@dataclass(frozen=True)
class Landing:
    """The end of a flight the loop flew off the ground at ``took_off_s``: at ``t_s``, and
    ``how`` (LANDED_HOME, LANDED_ELSEWHERE, BY_OPERATOR, FAILSAFE, LINK_LOST_IN_FLIGHT: the
    last two end it where the platform lost the vehicle, which may still fly); the vehicle's
    odometers then (``distance_m``, ``flight_s``), the highest altitude above its depot the
    loop saw since the take-off, the battery's charge in percent at the take-off and now
    (None: neither measured nor estimated), and its ``track``."""

    took_off_s: float
    t_s: float
    how: str
    distance_m: float
    flight_s: float
    max_alt_m: float | None
    battery_start_pct: float | None
    battery_end_pct: float | None
    # Where it flew: (t_s, lat, lng, alt, battery_pct or None) at each report of the flight
    # that moved it, the take-off's and the end's included.
    track: tuple[tuple[float, float, float, float, float | None], ...] = ()
    # The flight's telemetry log the driver recorded (an open binary file of a .tlog), if
    # it keeps one (``KeepsFlightLog``); else None: the store writes a simulated one.
    log: Any = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class VehicleState:
    """What the loop reports of its vehicle at ``t_s``; ``took_off_s``: it left the ground
    at that time since the last report (the loop flew it off from landed), else None;
    ``landing``: a flight of its ended since the last report (``Landing``), else None."""

    t_s: float
    position: Position
    phase: str
    distance_m: float
    flight_s: float
    planner_state: Any
    took_off_s: float | None = None
    landing: Landing | None = None


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
        """The vehicle is here now (``moved``: somewhere else than at the last record); a
        take-off it reports (``took_off_s``) opens a flight with its pilot in command then,
        a ``landing`` closes that flight, each written with this report or the next one."""
        ...

    def area(self) -> Area: ...

    def aboard(self) -> list[dict[str, Any]]:
        """The VVs aboard, for the live map (as of the last record)."""
        ...


@runtime_checkable
class MeasuredBattery(Protocol):
    """A driver that tells the battery's charge its vehicle reports (a MAVLink autopilot's
    SYS_STATUS), whatever endurance the loop plans with."""

    def battery_fraction(self) -> float | None: ...


@runtime_checkable
class ReportsTakeOver(Protocol):
    """A driver that says when a pilot or a failsafe took the vehicle over (the mode it
    switched to; None while the driver is in control)."""

    @property
    def took_over(self) -> str | None: ...


@runtime_checkable
class KeepsFlightLog(Protocol):
    """A driver that records its link's messages of a flight (a MAVLink driver's
    ``fleet.mavlink.tlog.TlogRecorder``): started at the take-off, finished at the landing
    (an open file of the .tlog, or None)."""

    @property
    def flight_log(self) -> Any: ...


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
