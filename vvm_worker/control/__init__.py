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

The loop keeps the flights it flies, from the take-off it commands to the landing it sees
(home, elsewhere, by an operator's command, after a failsafe took over) or to where the
platform lost the vehicle (its link, a take-over), and reports each end (``Landing``: the
odometers, the highest altitude, the battery) with its next report, as it reports take-offs.
A vehicle that starts in the air flies no flight of the loop's until it takes off.

The loop is built in parts, each on the one before (``state``, ``legs``, ``battery``,
``planning``, then ``loop``'s ``ControlLoop`` with its events); ``types`` holds what they
share with their callers.
"""

from vvm_worker.control.loop import ControlLoop
from vvm_worker.control.types import (
    ACTIVE,
    ARRIVAL_OVERDUE_S,
    ARRIVAL_POLL_S,
    BY_OPERATOR,
    CHARGE_POLL_S,
    CHARGING,
    FAILSAFE,
    HOME_RADIUS_M,
    LAND,
    LANDED_ELSEWHERE,
    LANDED_HOME,
    LINK_LOST_IN_FLIGHT,
    MAINTENANCE,
    NO_WAY,
    OFFLINE,
    PHASE_LANDING_DOWN,
    REACH_SLACK_M,
    RECENT_TASKS,
    RETURN_HOME,
    TURN_TOLERANCE_M,
    Area,
    Landing,
    LoopConfig,
    LoopTask,
    OperatorCommand,
    PlanElsewhere,
    Scheduler,
    Sensing,
    Store,
    VehicleState,
    no_sensors,
)

__all__ = [
    "ACTIVE",
    "ARRIVAL_OVERDUE_S",
    "ARRIVAL_POLL_S",
    "BY_OPERATOR",
    "CHARGE_POLL_S",
    "CHARGING",
    "FAILSAFE",
    "HOME_RADIUS_M",
    "LAND",
    "LANDED_ELSEWHERE",
    "LANDED_HOME",
    "LINK_LOST_IN_FLIGHT",
    "MAINTENANCE",
    "NO_WAY",
    "OFFLINE",
    "PHASE_LANDING_DOWN",
    "REACH_SLACK_M",
    "RECENT_TASKS",
    "RETURN_HOME",
    "TURN_TOLERANCE_M",
    "Area",
    "ControlLoop",
    "Landing",
    "LoopConfig",
    "LoopTask",
    "OperatorCommand",
    "PlanElsewhere",
    "Scheduler",
    "Sensing",
    "Store",
    "VehicleState",
    "no_sensors",
]
