"""The ``.tlog`` a simulated RV's flight would have had, had it been a ``mavsim`` flown over
MAVLink: the same messages, made by the simulator's own encoders (``sim/messages.py``), at the
rates the simulator streams them to the worker, along the flight's track.

A ground-station tool then opens a simulated flight's log as it opens a real one's.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from fleet.geo import Position, interpolate
from fleet.mavlink.modes import custom_mode_of
from fleet.mavlink.sim import messages
from fleet.mavlink.sim.flavours import ARDUCOPTER, Flavour
from fleet.mavlink.sim.flight import velocity_ned
from fleet.mavlink.tlog import tlog_entry
from fleet.mavlink.wire import mavlink

__all__ = ["SIM_LOG_INTERVALS_S", "simulated_tlog"]

# Seconds between messages: the simulator's default HEARTBEAT and SYS_STATUS, what the MAVLink
# driver asks of it (GLOBAL_POSITION_INT at its default 4 Hz, the extended status at 1 Hz).
SIM_LOG_INTERVALS_S: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "GLOBAL_POSITION_INT": 0.25,
    "SYS_STATUS": 1.0,
    "GPS_RAW_INT": 1.0,
    "VFR_HUD": 1.0,
}
_GPS_SATELLITES = 12
_GPS_HDOP = 0.8
_MODE = "GUIDED"  # what the driver flies an ArduPilot vehicle in
_SAME_TIME_S = 1e-9


@dataclass(frozen=True)
class _Sample:
    here: Position
    velocity: tuple[float, float, float]
    heading_deg: float | None
    battery: float


class _Frames:
    """A file for pymavlink's encoder: each frame it writes becomes a .tlog record at ``t_s``."""

    def __init__(self) -> None:
        self.t_s = 0.0
        self.out: list[bytes] = []

    def write(self, frame: bytes) -> None:
        self.out.append(tlog_entry(self.t_s, bytes(frame)))


def simulated_tlog(
    track: Sequence[tuple[float, float, float, float]],
    *,
    epoch_s: float,
    system_id: int,
    battery_start: float,
    battery_end: float,
    home: Position | None = None,
    ground_amsl_m: float = 0.0,
    flavour: Flavour = ARDUCOPTER,
    intervals_s: dict[str, float] | None = None,
) -> bytes:
    """The .tlog bytes of a simulated flight.

    ``track``: (t_s, lat, lng, alt) points on the platform clock, in time order, the vehicle
    flying straight between them (a VV's TrackPoints, a simulated vehicle's legs); alt is above
    the ground datum as ``fleet.geo.Position`` has it. ``epoch_s``: the platform clock's
    t = 0 as Unix epoch seconds (0 for the live system's wall clock, ``SIM_EPOCH_S`` for
    ``simulate``). ``system_id``: the vehicle's MAVLink system id. ``battery_start`` and
    ``battery_end``: its charge (0..1) at the first and last point, linear between.
    ``home``: where altitudes are relative to (the first point if None); ``ground_amsl_m``:
    the ground's altitude above mean sea level. ``flavour``: the autopilot the messages say
    (``sim/flavours.py``). ``intervals_s``: seconds between messages by type (default
    ``SIM_LOG_INTERVALS_S``).

    The vehicle is armed in GUIDED from the first point and disarms at the last (a last
    HEARTBEAT says so). Timestamps are ``epoch_s + t_s``; time_boot_ms counts from the first
    point. Raises ValueError for an empty track, a track that goes back in time or a message
    type the simulator does not send here.
    """
    if not track:
        raise ValueError("a flight log needs at least one track point")
    times = [p[0] for p in track]
    if any(b < a for a, b in itertools.pairwise(times)):
        raise ValueError("the track's times must not decrease")
    intervals = dict(SIM_LOG_INTERVALS_S if intervals_s is None else intervals_s)
    unknown = set(intervals) - set(SIM_LOG_INTERVALS_S)
    if unknown:
        raise ValueError(f"no simulated flight log message {sorted(unknown)}")
    points = [Position(lat, lng, alt) for _, lat, lng, alt in track]
    base = home if home is not None else points[0]
    start_s, end_s = times[0], times[-1]

    def sample(t_s: float) -> _Sample:
        here = _position(times, points, t_s)
        ahead_s = min(t_s + 0.1, end_s)
        if ahead_s - t_s > _SAME_TIME_S:
            velocity = velocity_ned(here, _position(times, points, ahead_s), ahead_s - t_s)
        else:
            velocity = (0.0, 0.0, 0.0)
        north, east, _ = velocity
        heading = (
            math.degrees(math.atan2(east, north)) % 360 if math.hypot(north, east) > 0.1 else None
        )
        span = end_s - start_s
        progress = (t_s - start_s) / span if span > 0 else 1.0
        battery = battery_start + (battery_end - battery_start) * progress
        return _Sample(here, velocity, heading, min(1.0, max(0.0, battery)))

    frames = _Frames()
    mav: Any = mavlink.MAVLink(frames, srcSystem=system_id, srcComponent=1)
    custom = custom_mode_of(flavour.autopilot, _MODE, flavour.mav_type)

    def heartbeat(armed: bool) -> Callable[[_Sample, int], None]:
        return lambda s, boot: messages.heartbeat(
            mav,
            mav_type=flavour.mav_type,
            autopilot=flavour.heartbeat_autopilot,
            custom_mode=custom,
            armed=armed,
            critical=s.battery < messages.CRITICAL_BATTERY,
        )

    senders: dict[str, Callable[[_Sample, int], None]] = {
        "HEARTBEAT": heartbeat(True),
        "GLOBAL_POSITION_INT": lambda s, boot: messages.global_position(
            mav,
            boot_ms=boot,
            here=s.here,
            home=base,
            ground_amsl_m=ground_amsl_m,
            velocity=s.velocity,
            heading_deg=s.heading_deg,
        ),
        "SYS_STATUS": lambda s, boot: messages.sys_status(
            mav, fraction=s.battery, prearm_ok=True, on_ground=False
        ),
        "GPS_RAW_INT": lambda s, boot: messages.gps_raw(
            mav,
            boot_ms=boot,
            fix={
                "lat": s.here.lat,
                "lng": s.here.lng,
                "alt": s.here.alt,
                "satellites": _GPS_SATELLITES,
                "hdop": _GPS_HDOP,
            },
            ground_amsl_m=ground_amsl_m,
            speed_mps=math.hypot(s.velocity[0], s.velocity[1]),
            heading_deg=s.heading_deg,
        ),
        "VFR_HUD": lambda s, boot: messages.vfr_hud(
            mav,
            speed_mps=math.hypot(s.velocity[0], s.velocity[1]),
            heading_deg=s.heading_deg,
            throttle_pct=50,
            alt_m=ground_amsl_m + s.here.alt,
            climb_mps=-s.velocity[2],
        ),
    }
    # Every message's times, merged in time order (type order at the same instant, as the
    # simulator's streams go out in one tick); the flight's last instant has them all.
    schedule: list[tuple[float, int, str]] = []
    order = list(SIM_LOG_INTERVALS_S)
    for kind, interval in intervals.items():
        if interval <= 0:
            raise ValueError(f"{kind}: the interval must be > 0")
        steps = int((end_s - start_s) / interval + _SAME_TIME_S)
        schedule += [(start_s + i * interval, order.index(kind), kind) for i in range(steps + 1)]
        if start_s + steps * interval < end_s - _SAME_TIME_S:
            schedule.append((end_s, order.index(kind), kind))
    schedule.sort()
    for t_s, _, kind in schedule:
        frames.t_s = epoch_s + t_s
        senders[kind](sample(t_s), messages.boot_ms(t_s - start_s))
    if "HEARTBEAT" in intervals:
        frames.t_s = epoch_s + end_s
        heartbeat(False)(sample(end_s), messages.boot_ms(end_s - start_s))  # landed, disarmed
    return b"".join(frames.out)


def _position(times: Sequence[float], points: Sequence[Position], t_s: float) -> Position:
    """Where the track is at ``t_s``: straight between its points, held beyond its ends."""
    i = bisect.bisect_right(times, t_s)
    if i == 0:
        return points[0]
    if i == len(times):
        return points[-1]
    t0, t1 = times[i - 1], times[i]
    if t1 - t0 <= _SAME_TIME_S:
        return points[i]
    return interpolate(points[i - 1], points[i], (t_s - t0) / (t1 - t0))
