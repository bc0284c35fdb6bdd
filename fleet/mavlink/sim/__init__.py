"""MavSim: a simulated copter that speaks MAVLink like ArduCopter (or, optionally, PX4).

``copter.py`` is the vehicle, ``missions.py`` its side of the mission protocol,
``flavours.py`` what differs between ArduCopter and PX4.

Any MAVLink ground station (MAVProxy, QGroundControl, a pymavlink script, ``MavlinkDriver``)
can fly it over a real link: it sends HEARTBEAT as a quadrotor with ArduCopter's custom mode
numbers and the armed flag, GLOBAL_POSITION_INT, SYS_STATUS, BATTERY_STATUS,
EXTENDED_SYS_STATE and HOME_POSITION at the rates asked for (MAV_CMD_SET_MESSAGE_INTERVAL,
MAV_CMD_REQUEST_MESSAGE, REQUEST_DATA_STREAM), answers every COMMAND_LONG and COMMAND_INT with a
COMMAND_ACK (UNSUPPORTED for commands it does not know), runs pre-arm checks (refusing with a
"PreArm: ..." STATUSTEXT and DENIED), takes off (MAV_CMD_NAV_TAKEOFF in GUIDED), follows
SET_POSITION_TARGET_GLOBAL_INT in GUIDED, returns (RTL mode, MAV_CMD_NAV_RETURN_TO_LAUNCH) and
lands (LAND mode, MAV_CMD_NAV_LAND) and disarms itself on the ground; it serves the parameter
protocol (a small set: the fence, battery capacity, speeds) and the mission protocol (keeping
what it received, e.g. fence polygons, and sending it back on request).

It flies with the in-process simulator's kinematics: a ``fleet.simulation.SimVehicle`` with
the vehicle's ``VehicleSpec`` (vertical take-off, straight legs at the maximum speed while
climbing at the climb rate, vertical landing), on a simulated clock that runs ``speed`` times
faster than the wall clock (``speed=0``: every flight ends at once). Its battery drains over
flight time (``spec.battery_s`` seconds of endurance); charging is not its business, but
ArduPilot's MAV_CMD_BATTERY_RESET (after a battery swap) sets the level. Message rates, time
outs and the link are on the wall clock.

Pure Python on pymavlink, no Django: tests run it in a thread (``start``/``stop``, or as a
context manager); ``manage.py mavsim`` runs it in the foreground. Test hooks: ``cut_link`` (it
goes silent and deaf, as if the radio died), ``ignore_command`` (never acknowledge a command
id), ``drop_incoming`` (lose the next messages of a type), ``set_battery``,
``fail_prearm``; and what it saw: ``commands_seen``, ``mission_items``, ``fence_polygons``,
``param``, ``message_interval_s``.
"""

from fleet.mavlink.sim.copter import MavSim
from fleet.mavlink.sim.flavours import FLAVOURS

__all__ = ["FLAVOURS", "MavSim"]
