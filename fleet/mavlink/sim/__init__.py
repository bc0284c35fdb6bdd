"""MavSim: a simulated copter that speaks MAVLink like ArduCopter (or, optionally, PX4), or a
rover, boat or submarine that speaks it like ArduRover and ArduSub (``frame``).

``copter.py`` (``MavSim``) wires the parts, runs them in its loop and has the API tests and
``manage.py mavsim`` use; each part is a module: ``transport.py`` (the connection, the loop
that reads it, a sender per component), ``flight.py`` (the kinematics on the simulated clock,
the battery), ``commands.py`` (COMMAND_LONG/COMMAND_INT and their ACKs; arming, modes and the
commands that fly), ``failsafes.py`` (what the autopilot does by itself: fence breaches, an
empty battery, disarming on the ground), ``telemetry.py`` with ``messages.py`` (streamed
messages and their rates), ``params.py`` (the parameter protocol), ``missions.py`` (the
mission protocol's transfers), ``auto.py`` (flying the mission in AUTO), ``guided.py`` with
``targets.py`` (GUIDED's targets and frames), ``fence.py`` (the geofence), ``payload.py`` with
``companion.py`` (the sensors: the simulated field at the vehicle) and ``camera.py`` (the
camera protocol and the image server); ``flavours.py`` says what differs between ArduCopter,
PX4, ArduRover and ArduSub.

With ``frame="rover"`` or ``"boat"`` it is ArduRover (HEARTBEAT type GROUND_ROVER or
SURFACE_BOAT, Rover/mode.h's mode numbers: HOLD 4, AUTO 10, RTL 11, GUIDED 15): it arms in
MANUAL, HOLD, GUIDED and the other manual modes, refuses NAV_TAKEOFF and NAV_LAND
(UNSUPPORTED), drives to GUIDED's targets in the plane (their altitude ignored) turning in
place first, stops in HOLD, drives home in RTL and stops there armed, and takes FS_ACTION on a
GCS failsafe. With ``frame="sub"`` it is ArduSub (SUBMARINE, ArduSub/defines.h's numbers:
GUIDED 4, SURFACE 9, MANUAL 19): GUIDED's targets may be below the surface (negative relative
altitudes: depths, in GLOBAL_POSITION_INT.relative_alt and VFR_HUD.alt too), SURFACE rises
where it is, and there is no RTL: home is GUIDED to home at 0, then a disarm. The kinematics
are the simulator's for the kind (``ground``, ``surface``, ``underwater``).

Any MAVLink ground station (MAVProxy, MAVSDK, QGroundControl, a pymavlink script,
``MavlinkDriver``) can fly it over a real link: it sends HEARTBEAT as a quadrotor with
ArduCopter's custom mode numbers and the armed flag, GLOBAL_POSITION_INT, SYS_STATUS and
SCALED_PRESSURE (2 Hz) from the start, and BATTERY_STATUS, EXTENDED_SYS_STATE, HOME_POSITION,
GPS_RAW_INT, MISSION_CURRENT, FENCE_STATUS and AUTOPILOT_VERSION at the rates asked for
(MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE, REQUEST_DATA_STREAM); it answers every
COMMAND_LONG and COMMAND_INT with a COMMAND_ACK (UNSUPPORTED for commands it does not know),
runs pre-arm checks (refusing with a "PreArm: ..." STATUSTEXT and DENIED) and takes off
(MAV_CMD_NAV_TAKEOFF in GUIDED).

In GUIDED it flies to the targets of MISSION_ITEM(_INT) with current=2 (MISSION_ACK),
MAV_CMD_DO_REPOSITION (switching to GUIDED with MAV_DO_REPOSITION_FLAGS_CHANGE_MODE),
SET_POSITION_TARGET_GLOBAL_INT and SET_POSITION_TARGET_LOCAL_NED (from home); frames it does
not fly are refused (MISSION_ACK UNSUPPORTED_FRAME, COMMAND_ACK DENIED, a STATUSTEXT for the
targets that have no answer). In AUTO (or on MAV_CMD_MISSION_START) it flies the uploaded
mission from item 1 (item 0 is home, as on ArduPilot): NAV_TAKEOFF, NAV_WAYPOINT (with its hold
time), NAV_LOITER_TIME, NAV_DELAY, NAV_RETURN_TO_LAUNCH and NAV_LAND, passing over other items, with
"Mission: N WP", MISSION_CURRENT and MISSION_ITEM_REACHED; MAV_CMD_DO_SET_MISSION_CURRENT and
MISSION_SET_CURRENT jump. It returns (RTL mode, MAV_CMD_NAV_RETURN_TO_LAUNCH) and lands (LAND
mode, MAV_CMD_NAV_LAND) and disarms itself on the ground.

It enforces its geofence when FENCE_ENABLE is 1: FENCE_ALT_MAX, FENCE_RADIUS around home and
the polygons received with the mission protocol (MAV_MISSION_TYPE_FENCE: inside every
inclusion polygon, outside every exclusion polygon), as FENCE_TYPE selects. Leaving it while flying is a breach: "Polygon fence breached" (NOTICE),
FENCE_STATUS (breach_status, breach_count, breach_type, breach_time) and FENCE_ACTION (0 report
only, 1 RTL (the default), 2 land, ...); a GUIDED target outside is refused, as ArduCopter's
ModeGuided::set_destination refuses it, so no breach follows (a mission may lead out, and
then the breach brings it back). It serves the parameter protocol (a small set: the fence,
battery capacity, speeds) and the mission protocol (keeping what it received and sending it
back on request).

Its sensors read ``fleet.simulation.SensorField(field_seed)`` where the vehicle is, at the
simulated time, with the default catalog's sensors: the barometer and thermometer in
SCALED_PRESSURE, the GPS fix in GPS_RAW_INT. With ``payload=True`` (``manage.py mavsim``'s
default) it is also two more components, each with its own HEARTBEAT: the companion computer
(MAV_COMP_ID_ONBOARD_COMPUTER) sending NAMED_VALUE_FLOAT "CO2" and "NOx" at 2 Hz, and the
camera (MAV_COMP_ID_CAMERA: CAMERA_INFORMATION, MAV_CMD_IMAGE_START_CAPTURE then
CAMERA_IMAGE_CAPTURED whose ``file_url`` points at an HTTP server it runs on
``camera_url_host``, serving the "Camera 640x480" image ``render_camera`` draws there).

It flies with the in-process simulator's kinematics: a ``fleet.simulation.SimVehicle`` with
the vehicle's ``VehicleSpec`` (vertical take-off, straight legs at the maximum speed while
climbing at the climb rate, vertical landing), on a simulated clock that runs ``speed`` times
faster than the wall clock (``speed=0``: every flight and wait ends at once). Its battery
drains over flight time (``spec.battery_s`` seconds of endurance); charging is not its
business, but ArduPilot's MAV_CMD_BATTERY_RESET (after a battery swap) sets the level. Message
rates, time outs and the link are on the wall clock.

Pure Python on pymavlink, no Django: tests run it in a thread (``start``/``stop``, or as a
context manager); ``manage.py mavsim`` runs it in the foreground. Test hooks: ``cut_link`` (it
goes silent and deaf, as if the radio died), ``ignore_command`` (never acknowledge a command
id), ``drop_incoming`` (lose the next messages of a type), ``set_battery``,
``fail_prearm``; and what it saw or did: ``commands_seen``, ``mission_items``,
``fence_polygons``, ``fence_status``, ``mission_current``, ``camera_captures`` (and
``camera_port``), ``texts_sent``, ``param``, ``message_interval_s``.
"""

from fleet.mavlink.sim.copter import MavSim
from fleet.mavlink.sim.flavours import FLAVOURS, FRAME_OF_KIND, FRAMES

__all__ = ["FLAVOURS", "FRAMES", "FRAME_OF_KIND", "MavSim"]
