"""A vehicle as its control loop drives it: the ``Driver`` protocol and its error.

Two drivers implement it: a simulated vehicle (``fleet.simulation.SimVehicle``) and a MAVLink
autopilot (``fleet.mavlink.driver.MavlinkDriver``). The loop (``vvm_worker.control``) knows only
this module: a driver that cannot do what it is asked raises ``DriverError`` (the MAVLink
driver's errors are kinds of it), never a type of its link.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

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


LINK_LOST = "link lost"
"""The reason an RV whose link died is offline for, whoever sees it first: the driver's link
watch or the control loop, whose command found the link down."""


class LinkDown(DriverError):
    """The vehicle does not answer: its link is gone (not permanent, a radio link often comes
    back). The loop takes the vehicle offline for ``LINK_LOST``, as the link watch does, so that
    the reason does not depend on which of them saw it first."""

    permanent = False


class SensorFailure(Exception):
    """A reading the vehicle did not give: its sensor did not answer in time, its link is
    gone, its camera refused. ``reason`` says why in words a customer may read (no port, no
    address, no vehicle); the message adds where, for the operator's log. The task ends with
    the reason as its error: a reading is never invented."""

    def __init__(self, reason: str, *, where: str = "") -> None:
        super().__init__(f"{where}: {reason}" if where else reason)
        self.reason = reason


@dataclass(frozen=True)
class SensorRead:
    """What a control loop asks of a vehicle's own sensor: the SDC entry (``sensor``: its
    name, ``kind``, ``params``) and where the vehicle gets it (``source``: ``telemetry``,
    ``named_value``, ``camera``; ``name``: the NAMED_VALUE_FLOAT name), taken no earlier than
    ``since_s`` (platform time: the vehicle's arrival) and within ``timeout_s``."""

    sensor: str
    kind: str
    source: str
    params: Mapping[str, Any] = field(default_factory=dict)
    name: str = ""
    since_s: float = 0.0
    timeout_s: float = 2.0


@dataclass(frozen=True)
class Sample:
    """One reading as the vehicle took it: its kind-specific fields (``value`` for a scalar;
    ``lat``, ``lng``, ``alt``, ``satellites``, ``hdop`` for GPS; ``width``, ``height``,
    ``format`` for a camera, with the picture's bytes in ``image``), the vehicle's own time
    (epoch milliseconds) and position at the moment it was taken."""

    fields: Mapping[str, Any]
    epoch_ms: int
    position: Position
    image: bytes | None = None


class Driver(Protocol):
    """The vehicle link: commands (which may raise ``DriverError``) and what the vehicle
    reports or the kinematics estimate, at platform time ``t`` (seconds). ``depot``: where it
    takes off and lands. ``measures_battery``: its battery's charge is measured (telemetry),
    not estimated from the time flown. ``reports_arrival``: where it is comes from telemetry,
    so an arrival is looked for from the start (an estimate may be late), not at the
    estimated time."""

    depot: Position
    measures_battery: bool
    reports_arrival: bool

    def fly_to(self, target: Position, now_s: float) -> float:
        """Send the vehicle to ``target``; returns the estimated arrival time."""
        ...

    def return_to_depot(self, now_s: float) -> float:
        """Send the vehicle home to land; returns the estimated landing time."""
        ...

    def land(self, now_s: float) -> float:
        """Land where the vehicle is now (an operator's "land now"); returns the estimated
        touchdown time (``now_s`` when it is landed already)."""
        ...

    def recharge(self, now_s: float, duration_s: float) -> float:
        """When a charge of ``duration_s`` started now (landed) is done."""
        ...

    def position_at(self, t: float) -> Position: ...
    def phase_at(self, t: float) -> str: ...
    def is_landed_at(self, t: float) -> bool: ...
    def has_arrived(self, target: Position, tolerance_m: float, now_s: float) -> bool: ...
    def distance_m(self, t: float) -> float: ...
    def speed_at(self, t: float) -> float:
        """Ground speed in metres a second at ``t`` (the driver's time scale)."""
        ...

    def flight_s(self, t: float) -> float: ...
    def battery_remaining_s(self, t: float) -> float | None: ...
    def time_to_s(self, target: Position, now_s: float) -> float: ...
    def time_home_s(self, start: Position) -> float: ...
    def leg_s(self, a: Position, b: Position) -> float:
        """Estimated seconds of a straight leg in the air from ``a`` to ``b``."""
        ...

    def read_sensor(self, read: SensorRead) -> Sample:
        """A reading of one of the vehicle's own sensors; raises ``SensorFailure`` when it
        does not come (a simulated vehicle has none: its readings come from the field)."""
        ...
