"""MAVLink for CPCC: a link to an autopilot, a driver that flies it, and a simulated copter.

Pure Python on pymavlink, no Django (docs/mavlink.md tells the whole story):

- ``MavlinkLink`` (``link.py``): a connection (``endpoint.py`` for the connection strings),
  heartbeats both ways with link-loss detection, commands with COMMAND_ACK, retries and
  timeouts, message rates, parameters, and the mission protocol (for the geofence).
- ``MavlinkDriver`` (``driver.py``): one ArduPilot or PX4 copter behind the RV control loop's
  driver API (``fly_to``, ``return_to_depot``, ``position_at``, ...), plus ``connect``,
  ``upload_fence``, ``has_arrived``, ``battery_fraction``, ``link_ok`` and ``close``.
- ``MavSim`` (``sim/``): a copter that speaks MAVLink like ArduCopter, flying the in-process
  simulator's kinematics, for tests and ``manage.py mavsim``.
- ``errors.py``: typed errors that say whether a failure is permanent.
"""

from fleet.mavlink.driver import MavlinkDriver
from fleet.mavlink.endpoint import Endpoint, parse_endpoint
from fleet.mavlink.errors import (
    CommandDenied,
    CommandTimeout,
    LinkError,
    LinkLost,
    MavlinkError,
    MavlinkTimeout,
    MissionRejected,
    MissionTimeout,
    ModeChangeFailed,
    ParamRejected,
    ParamTimeout,
    PreArmFailed,
    UnsupportedVehicle,
    VehicleTookOver,
)
from fleet.mavlink.link import CommandAck, Heartbeat, MavlinkLink, StatusText
from fleet.mavlink.mission import MissionItem, fence_polygon_items, inclusion_polygons
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.sim import MavSim

__all__ = [
    "Autopilot",
    "CommandAck",
    "CommandDenied",
    "CommandTimeout",
    "Endpoint",
    "Heartbeat",
    "LinkError",
    "LinkLost",
    "MavSim",
    "MavlinkDriver",
    "MavlinkError",
    "MavlinkLink",
    "MavlinkTimeout",
    "MissionItem",
    "MissionRejected",
    "MissionTimeout",
    "ModeChangeFailed",
    "ParamRejected",
    "ParamTimeout",
    "PreArmFailed",
    "StatusText",
    "UnsupportedVehicle",
    "VehicleTookOver",
    "fence_polygon_items",
    "inclusion_polygons",
    "parse_endpoint",
]
