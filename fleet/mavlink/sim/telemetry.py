"""What the simulated autopilot streams, and how often.

``Streams`` keeps the rate of each message (MAV_CMD_SET_MESSAGE_INTERVAL, the older
REQUEST_DATA_STREAM groups, the defaults) and sends what is due; ``Telemetry`` makes each
message of the vehicle's state (with ``messages.py``) and answers the commands that ask for
messages.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from fleet.kinds import UNDERWATER
from fleet.mavlink.modes import custom_mode_of
from fleet.mavlink.sim import messages
from fleet.mavlink.sim.camera import Shot
from fleet.mavlink.sim.commands import Outcome
from fleet.mavlink.sim.companion import FieldSensors
from fleet.mavlink.sim.fence import FenceStatus
from fleet.mavlink.sim.flavours import Flavour
from fleet.mavlink.sim.flight import Flight
from fleet.mavlink.sim.transport import Build, reply_to
from fleet.mavlink.wire import mavlink

# What streams from the start (wall seconds between messages), and what interval 0 restores.
DEFAULT_INTERVALS: Mapping[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE: 0.5,
}
# REQUEST_DATA_STREAM's groups, as ArduPilot fills them (of the messages simulated).
DATA_STREAMS: Mapping[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_POSITION: (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,),
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (
        mavlink.MAVLINK_MSG_ID_SYS_STATUS,
        mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,
        mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
        mavlink.MAVLINK_MSG_ID_MISSION_CURRENT,
        mavlink.MAVLINK_MSG_ID_FENCE_STATUS,
        mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    ),
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: (mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE,),
    mavlink.MAV_DATA_STREAM_EXTRA2: (mavlink.MAVLINK_MSG_ID_VFR_HUD,),
}
_MIN_INTERVAL_S = 0.005  # 200 Hz at most


class Streams:
    """Message rates and the senders of the streamed messages (by message id). ``wall`` is
    the wall clock in seconds."""

    def __init__(self, senders: Mapping[int, Callable[[], None]], wall: Callable[[], float]):
        self.senders = senders
        self._wall = wall
        self.intervals: dict[int, float] = dict(DEFAULT_INTERVALS)
        self._next_due: dict[int, float] = {}
        self.statustext_on = True

    def send_due(self) -> None:
        wall = self._wall()
        for message_id, interval in list(self.intervals.items()):
            sender = self.senders.get(message_id)
            if sender is None:
                continue
            due = self._next_due.get(message_id, wall)
            if wall >= due:
                sender()
                # Keep the cadence, but never try to catch up a backlog.
                self._next_due[message_id] = max(due + interval, wall)

    def due_now(self, message_id: int) -> None:
        """Send a message with the next ``send_due`` (a new ground station hears it at once)."""
        self._next_due[message_id] = self._wall()

    def sent_now(self, message_id: int) -> None:
        """A message just went out of turn: the next one is a full interval later."""
        self._next_due[message_id] = self._wall() + self.intervals.get(message_id, 1.0)

    def set_interval(self, message_id: int, interval_us: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL: microseconds, -1 off, 0 the default; the MAV_RESULT."""
        if message_id == mavlink.MAVLINK_MSG_ID_STATUSTEXT:
            # STATUSTEXT is sent when there is something to say; -1 silences it.
            self.statustext_on = interval_us >= 0
            return int(mavlink.MAV_RESULT_ACCEPTED)
        if message_id not in self.senders:
            return int(mavlink.MAV_RESULT_DENIED)
        if interval_us < 0:
            self.intervals.pop(message_id, None)
        elif interval_us == 0:
            # 0: the default rate (what it streams at start, otherwise off).
            if message_id in DEFAULT_INTERVALS:
                self.intervals[message_id] = DEFAULT_INTERVALS[message_id]
            else:
                self.intervals.pop(message_id, None)
        else:
            self.intervals[message_id] = max(interval_us / 1e6, _MIN_INTERVAL_S)
        self._next_due.pop(message_id, None)
        return int(mavlink.MAV_RESULT_ACCEPTED)

    def on_request_data_stream(self, msg: Any) -> None:
        """REQUEST_DATA_STREAM: the older rate interface MAVProxy and QGroundControl still use
        with ArduPilot (a group of messages at a rate in Hz, or off)."""
        if msg.req_stream_id == mavlink.MAV_DATA_STREAM_ALL:
            ids = [i for group in DATA_STREAMS.values() for i in group]
        else:
            ids = list(DATA_STREAMS.get(msg.req_stream_id, ()))
        rate = float(msg.req_message_rate)
        for message_id in ids:
            self.set_interval(message_id, 1e6 / rate if msg.start_stop and rate > 0 else -1.0)


class Status(Protocol):
    """The autopilot's state as its messages report it (``commands.Commander``)."""

    @property
    def armed(self) -> bool: ...

    @property
    def mode(self) -> str: ...

    def arming_refusal(self) -> str | None:
        """Why arming would be refused now, or None."""
        ...


class Telemetry:
    """The autopilot's messages, made of the vehicle's state: ``status`` (arming and mode),
    ``flight`` (where it is, its battery), ``sensors`` (barometer, thermometer, GPS) and
    ``fence_status``; ``ground_amsl_m`` is the ground's altitude above mean sea level,
    ``capacity_mah`` the battery's. ``streams`` sends them at their rates (MISSION_CURRENT with
    ``mission_current``). ``send`` sends from the autopilot, ``wall`` is the wall clock."""

    def __init__(
        self,
        status: Status,
        flight: Flight,
        sensors: FieldSensors,
        fence_status: FenceStatus,
        *,
        flavour: Flavour,
        ground_amsl_m: float,
        capacity_mah: int,
        mission_current: Callable[[], None],
        send: Callable[[Build], None],
        wall: Callable[[], float],
    ) -> None:
        self._status = status
        self._flight = flight
        self._sensors = sensors
        self._fence_status = fence_status
        self._flavour = flavour
        self._ground_amsl_m = ground_amsl_m
        self._capacity_mah = capacity_mah
        self._send = send
        self._wall = wall
        self.gcs_heartbeats = 0  # received from ground stations and companions
        self.gcs_seen_wall: float | None = None  # when the last of them came (wall clock)
        self._gcs_seen: set[tuple[int, int]] = set()
        self._announced: tuple[bool, str] | None = None  # (armed, mode) of the last HEARTBEAT
        self.streams = Streams(
            {
                mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._send_heartbeat,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._send_position,
                mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._send_sys_status,
                mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self._send_battery_status,
                mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._send_home,
                mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._send_extended_state,
                mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
                mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: mission_current,
                mavlink.MAVLINK_MSG_ID_FENCE_STATUS: self._send_fence_status,
                mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE: self._send_scaled_pressure,
                mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._send_gps_raw,
                mavlink.MAVLINK_MSG_ID_VFR_HUD: self._send_vfr_hud,
            },
            wall,
        )

    def tick(self) -> None:
        """Send what is due."""
        if self._announced != (self._status.armed, self._status.mode):
            # A mode or arming change goes out at once rather than with the next 1 Hz
            # heartbeat (ArduPilot waits for the next one): a GCS that confirms a change by
            # the heartbeat then waits milliseconds, not a second.
            self._send_heartbeat()
            self.streams.sent_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
        self.streams.send_due()

    def handle(self, msg: Any) -> bool:
        """Handle a HEARTBEAT or REQUEST_DATA_STREAM; returns whether it did."""
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg)
        elif kind == "REQUEST_DATA_STREAM":
            self.streams.on_request_data_stream(msg)
        else:
            return False
        return True

    def _on_heartbeat(self, msg: Any) -> None:
        # A new ground station (or companion) hears ours at once instead of within a second.
        if msg.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER):
            return
        self.gcs_heartbeats += 1
        self.gcs_seen_wall = self._wall()
        source = reply_to(msg)
        if source not in self._gcs_seen:
            self._gcs_seen.add(source)
            self.streams.due_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)

    def command(self, command: int, p: tuple[float, ...]) -> Outcome | None:
        """Run a command that asks for messages (their rates, or one now): its MAV_RESULT and
        what to send after the ACK; None for any other command."""
        accepted = mavlink.MAV_RESULT_ACCEPTED
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self.streams.set_interval(round(p[0]), p[1]), None
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            message_id = round(p[0])
            interval = self.streams.intervals.get(message_id)
            interval_us = round(interval * 1e6) if interval is not None else -1
            return accepted, lambda: self._send(
                lambda mav: mav.message_interval_send(message_id, interval_us)
            )
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            sender = self.streams.senders.get(round(p[0]))
            if sender is None:
                return mavlink.MAV_RESULT_DENIED, None
            return accepted, sender
        if command == mavlink.MAV_CMD_GET_HOME_POSITION:
            return accepted, self._send_home
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return accepted, self._send_autopilot_version
        return None

    def shot(self) -> Shot:
        """Where the vehicle is as the camera takes a picture."""
        flight = self._flight
        now = flight.now()
        here = flight.position_at(now)
        return Shot(
            position=here,
            amsl_m=self._ground_amsl_m + here.alt,
            relative_m=here.alt - flight.home.alt,
            heading_deg=flight.heading_deg(now),
            time_s=now,
        )

    def _boot_ms(self) -> int:
        return messages.boot_ms(self._wall())

    def _send_heartbeat(self) -> None:
        status, flavour = self._status, self._flavour
        self._announced = (status.armed, status.mode)
        autopilot = flavour.heartbeat_autopilot
        custom = custom_mode_of(flavour.autopilot, status.mode, flavour.mav_type)
        armed, critical = status.armed, self._flight.battery_failsafe
        self._send(
            lambda mav: messages.heartbeat(
                mav,
                mav_type=flavour.mav_type,
                autopilot=autopilot,
                custom_mode=custom,
                armed=armed,
                critical=critical,
            )
        )

    def _send_position(self) -> None:
        flight = self._flight
        now = flight.now()
        here = flight.position_at(now)
        velocity, heading = flight.velocity(now), flight.heading_deg(now)
        boot = self._boot_ms()
        self._send(
            lambda mav: messages.global_position(
                mav,
                boot_ms=boot,
                here=here,
                home=flight.home,
                ground_amsl_m=self._ground_amsl_m,
                velocity=velocity,
                heading_deg=heading,
            )
        )

    def _send_sys_status(self) -> None:
        fraction = self._flight.battery(self._flight.now())
        prearm_ok = self._status.arming_refusal() is None
        on_ground = self._flight.on_ground
        self._send(
            lambda mav: messages.sys_status(
                mav, fraction=fraction, prearm_ok=prearm_ok, on_ground=on_ground
            )
        )

    def _send_battery_status(self) -> None:
        flight = self._flight
        fraction = flight.battery(flight.now())
        on_ground = flight.on_ground
        self._send(
            lambda mav: messages.battery_status(
                mav,
                fraction=fraction,
                battery_s=flight.spec.battery_s,
                capacity_mah=self._capacity_mah,
                on_ground=on_ground,
            )
        )

    def _send_home(self) -> None:
        home = self._flight.home
        self._send(
            lambda mav: messages.home_position(mav, home=home, ground_amsl_m=self._ground_amsl_m)
        )

    def _send_scaled_pressure(self) -> None:
        # The barometer and thermometer of the default catalog, read from the simulated field.
        here, now = self._flight.where()
        pressure = self._sensors.value("pressure", here, now)
        temperature = self._sensors.value("temperature", here, now)
        boot = self._boot_ms()
        self._send(
            lambda mav: messages.scaled_pressure(
                mav, boot_ms=boot, pressure_hpa=pressure, temperature_c=temperature
            )
        )

    def _send_gps_raw(self) -> None:
        # The receiver's own fix, a few metres off the position GLOBAL_POSITION_INT reports.
        here, now = self._flight.where()
        fix = self._sensors.gps(here, now)
        north, east, _ = self._flight.velocity(now)
        heading = self._flight.heading_deg(now)
        boot = self._boot_ms()
        self._send(
            lambda mav: messages.gps_raw(
                mav,
                boot_ms=boot,
                fix=fix,
                ground_amsl_m=self._ground_amsl_m,
                speed_mps=math.hypot(north, east),
                heading_deg=heading,
            )
        )

    def _send_fence_status(self) -> None:
        self._send(self._fence_status.send)

    def _send_vfr_hud(self) -> None:
        flight = self._flight
        now = flight.now()
        here = flight.position_at(now)
        north, east, down = flight.velocity(now)
        heading = flight.heading_deg(now)
        if flight.spec.kind == UNDERWATER:
            alt = here.alt - flight.home.alt  # ArduSub's VFR_HUD.alt is the depth (below 0)
        else:
            alt = self._ground_amsl_m + here.alt
        throttle = 0 if flight.on_ground else 50
        self._send(
            lambda mav: messages.vfr_hud(
                mav,
                speed_mps=math.hypot(north, east),
                heading_deg=heading,
                throttle_pct=throttle,
                alt_m=alt,
                climb_mps=-down,
            )
        )

    def _send_extended_state(self) -> None:
        flight = self._flight
        if not flight.takes_off:
            # Nothing a rover, boat or sub does is a take-off or landing: parked, or under way
            # (which no landed state names).
            parked = flight.on_ground
            landed = (
                mavlink.MAV_LANDED_STATE_ON_GROUND if parked else mavlink.MAV_LANDED_STATE_UNDEFINED
            )
        elif flight.on_ground:
            landed = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif flight.stage == "takeoff":
            landed = mavlink.MAV_LANDED_STATE_TAKEOFF
        elif flight.stage == "landing":
            landed = mavlink.MAV_LANDED_STATE_LANDING
        else:
            landed = mavlink.MAV_LANDED_STATE_IN_AIR
        self._send(lambda mav: messages.extended_sys_state(mav, landed_state=landed))

    def _send_autopilot_version(self) -> None:
        bytewise = self._flavour.bytewise_params
        self._send(lambda mav: messages.autopilot_version(mav, bytewise_params=bytewise))
