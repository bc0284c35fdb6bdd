"""Route planners for one vehicle: in which order to serve the open point tasks aboard.

Pure Python (numpy, no Django). A worker builds a planner with `make_planner(name, cost=...)`,
calls `next_task(position, open_tasks)` whenever the vehicle arrives somewhere or gets new work,
draws `route(...)` on the live map and persists `state()` / `restore()` with the vehicle.
"""

from .base import CostFn, Planner, PlanTask
from .exact import ExactResult, solve_open_path
from .planners import (
    DEFAULT_PLANNER,
    GATED_TOUR_LIMIT,
    PLANNER_NAMES,
    FcfsPlanner,
    GatedTspPlanner,
    NearestPlanner,
    TourPlanner,
    make_planner,
)

__all__ = [
    "DEFAULT_PLANNER",
    "GATED_TOUR_LIMIT",
    "PLANNER_NAMES",
    "CostFn",
    "ExactResult",
    "FcfsPlanner",
    "GatedTspPlanner",
    "NearestPlanner",
    "PlanTask",
    "Planner",
    "TourPlanner",
    "make_planner",
    "solve_open_path",
]
