"""A vehicle as its control loop drives it: the ``Driver`` protocol and its error.

Two drivers implement it: a simulated vehicle (``fleet.simulation.SimVehicle``) and a MAVLink
autopilot (``fleet.mavlink.driver.MavlinkDriver``). The loop (``vvm_worker.control``) knows only
this module: a driver that cannot do what it is asked raises ``DriverError`` (the MAVLink
driver's errors are kinds of it), never a type of its link.
"""

from __future__ import annotations

from typing import Protocol

from fleet.geo import Position


class DriverError(Exception):
    """The vehicle cannot do what it was asked: its link is gone, its autopilot refused, a
    pilot took over. ``permanent``: doing the same again cannot work until something changes
    (an operator, the vehicle's state); False when a retry later may succeed."""

    permanent: bool = False

    def __init__(self, message: str, *, permanent: bool | None = None) -> None:
        super().__init__(message)
        if permanent is not None:
            self.permanent = permanent


class Driver(Protocol):
    """The vehicle link: commands (which may raise ``DriverError``) and what the vehicle
    reports or the kinematics estimate, at platform time ``t`` (seconds)."""

    def fly_to(self, target: Position, now_s: float) -> float:
        """Send the vehicle to ``target``; returns the estimated arrival time."""
        ...

    def return_to_depot(self, now_s: float) -> float:
        """Send the vehicle home to land; returns the estimated landing time."""
        ...

    def recharge(self, now_s: float, duration_s: float) -> float:
        """When a charge of ``duration_s`` started now (landed) is done."""
        ...

    def position_at(self, t: float) -> Position: ...
    def phase_at(self, t: float) -> str: ...
    def is_landed_at(self, t: float) -> bool: ...
    def has_arrived(self, target: Position, tolerance_m: float, now_s: float) -> bool: ...
    def distance_m(self, t: float) -> float: ...
    def flight_s(self, t: float) -> float: ...
    def battery_remaining_s(self, t: float) -> float | None: ...
    def time_to_s(self, target: Position, now_s: float) -> float: ...
    def time_home_s(self, start: Position) -> float: ...
