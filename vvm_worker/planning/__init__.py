"""Route planners for one vehicle: in which order to serve the open point tasks aboard.

Pure Python (numpy, no Django). A worker builds a planner with `make_planner(name, cost=...)`,
calls `next_task(position, open_tasks)` whenever the vehicle arrives somewhere or gets new work,
draws `route(...)` on the live map and persists `state()` / `restore()` with the vehicle.
"""

from .base import CostFn, Planner, PlanTask
from .costs import NO_WAY_COST, AroundZones, TravelTime
from .deadlines import arrivals, by_deadline, deadline_of
from .exact import ExactResult, solve_open_path
from .planners import (
    DEFAULT_PLANNER,
    GATED_TOUR_LIMIT,
    PLANNER_NAMES,
    FcfsPlanner,
    GatedTspPlanner,
    LatencyPlanner,
    NearestPlanner,
    TourPlanner,
    make_planner,
)
from .repairman import best_insertion, insertion_cost
from .standby import STANDBY_S, standby_position

__all__ = [
    "DEFAULT_PLANNER",
    "GATED_TOUR_LIMIT",
    "NO_WAY_COST",
    "PLANNER_NAMES",
    "STANDBY_S",
    "AroundZones",
    "CostFn",
    "ExactResult",
    "FcfsPlanner",
    "GatedTspPlanner",
    "LatencyPlanner",
    "NearestPlanner",
    "PlanTask",
    "Planner",
    "TourPlanner",
    "TravelTime",
    "arrivals",
    "best_insertion",
    "by_deadline",
    "deadline_of",
    "insertion_cost",
    "make_planner",
    "solve_open_path",
    "standby_position",
]
