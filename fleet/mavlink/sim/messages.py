"""The autopilot's messages, built from plain values (pymavlink's MAVLink object first): what
``telemetry.py`` sends of the vehicle's state."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fleet.geo import Position
from fleet.mavlink.wire import mavlink

CELLS = 4  # a 4S LiPo: 16.8 V full, 14.0 V empty
_CELL_FULL_V = 4.2
_CELL_EMPTY_V = 3.5
LOW_BATTERY = 0.2  # BATTERY_STATUS says LOW below it, and the autopilot warns
CRITICAL_BATTERY = 0.1
_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
)
_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
)


def boot_ms(wall_s: float) -> int:
    """The wall clock (seconds since boot) as a message's time_boot_ms."""
    return int(wall_s * 1000) & 0xFFFFFFFF


def clamp16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


def voltage_mv(fraction: float) -> int:
    cell = _CELL_EMPTY_V + (_CELL_FULL_V - _CELL_EMPTY_V) * fraction
    return round(cell * CELLS * 1000)


def current_ca(on_ground: bool) -> int:
    return 50 if on_ground else 1500  # 0.5 A idle, 15 A hovering or cruising


def heartbeat(
    mav: Any,
    *,
    autopilot: int,
    custom_mode: int,
    armed: bool,
    critical: bool,
    mav_type: int = mavlink.MAV_TYPE_QUADROTOR,
) -> None:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if critical:
        status = mavlink.MAV_STATE_CRITICAL
    else:
        status = mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY
    mav.heartbeat_send(mav_type, autopilot, base, custom_mode, status)


def global_position(
    mav: Any,
    *,
    boot_ms: int,
    here: Position,
    home: Position,
    ground_amsl_m: float,
    velocity: tuple[float, float, float],
    heading_deg: float | None,
) -> None:
    north, east, down = velocity
    heading = 65535 if heading_deg is None else round(heading_deg * 100) % 36000
    mav.global_position_int_send(
        boot_ms,
        round(here.lat * 1e7),
        round(here.lng * 1e7),
        round((ground_amsl_m + here.alt) * 1000),
        round((here.alt - home.alt) * 1000),
        clamp16(north * 100),
        clamp16(east * 100),
        clamp16(down * 100),
        heading,
    )


def sys_status(mav: Any, *, fraction: float, prearm_ok: bool, on_ground: bool) -> None:
    health = _SENSORS | (mavlink.MAV_SYS_STATUS_PREARM_CHECK if prearm_ok else 0)
    present = _SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK
    mav.sys_status_send(
        present,
        present,
        health,
        200,  # load, per mille
        voltage_mv(fraction),
        current_ca(on_ground),
        round(fraction * 100),
        0,
        0,
        0,
        0,
        0,
        0,
    )


def battery_status(
    mav: Any, *, fraction: float, battery_s: float | None, capacity_mah: int, on_ground: bool
) -> None:
    if fraction <= 0.0:
        state = mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY
    elif fraction < CRITICAL_BATTERY:
        state = mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
    elif fraction < LOW_BATTERY:
        state = mavlink.MAV_BATTERY_CHARGE_STATE_LOW
    else:
        state = mavlink.MAV_BATTERY_CHARGE_STATE_OK
    remaining_s = round(fraction * battery_s) if battery_s is not None else 0
    cell_mv = voltage_mv(fraction) // CELLS
    # Per-cell voltages, the unused cells UINT16_MAX as the message asks.
    cells = [cell_mv] * CELLS + [65535] * (10 - CELLS)
    mav.battery_status_send(
        0,
        mavlink.MAV_BATTERY_FUNCTION_ALL,
        mavlink.MAV_BATTERY_TYPE_LIPO,
        32767,  # INT16_MAX: temperature unknown
        cells,
        current_ca(on_ground),
        round((1.0 - fraction) * capacity_mah),
        -1,  # energy consumed: unknown
        round(fraction * 100),
        remaining_s,
        state,
    )


def home_position(mav: Any, *, home: Position, ground_amsl_m: float) -> None:
    mav.home_position_send(
        round(home.lat * 1e7),
        round(home.lng * 1e7),
        round((ground_amsl_m + home.alt) * 1000),
        0.0,
        0.0,
        0.0,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
    )


def vfr_hud(
    mav: Any,
    *,
    speed_mps: float,
    heading_deg: float | None,
    throttle_pct: int,
    alt_m: float,
    climb_mps: float,
) -> None:
    """The HUD: ground speed (as airspeed too), heading (degrees, 0 when there is none),
    throttle, altitude and climb rate."""
    heading = 0 if heading_deg is None else round(heading_deg) % 360
    mav.vfr_hud_send(speed_mps, speed_mps, heading, throttle_pct, alt_m, climb_mps)


def extended_sys_state(mav: Any, *, landed_state: int) -> None:
    mav.extended_sys_state_send(mavlink.MAV_VTOL_STATE_UNDEFINED, landed_state)


def autopilot_version(mav: Any, *, bytewise_params: bool) -> None:
    capabilities = _CAPABILITIES | (
        mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        if bytewise_params
        else mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    )
    version = 4 << 24 | 5 << 16 | 0 << 8 | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL
    mav.autopilot_version_send(capabilities, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0)


def scaled_pressure(mav: Any, *, boot_ms: int, pressure_hpa: float, temperature_c: float) -> None:
    """The barometer: absolute pressure in hPa, its temperature in centi-degrees Celsius."""
    mav.scaled_pressure_send(boot_ms, pressure_hpa, 0.0, clamp16(temperature_c * 100))


def gps_raw(
    mav: Any,
    *,
    boot_ms: int,
    fix: Mapping[str, Any],
    ground_amsl_m: float,
    speed_mps: float,
    heading_deg: float | None,
) -> None:
    """The receiver's own fix (a ``SensorField`` GPS sample: lat, lng, alt, satellites, hdop)."""
    mav.gps_raw_int_send(
        boot_ms * 1000,
        mavlink.GPS_FIX_TYPE_3D_FIX,
        round(fix["lat"] * 1e7),
        round(fix["lng"] * 1e7),
        round((ground_amsl_m + fix["alt"]) * 1000),
        round(fix["hdop"] * 100),
        round(fix["hdop"] * 150),  # VDOP: about 1.5 times HDOP
        min(round(speed_mps * 100), 65534),
        65535 if heading_deg is None else round(heading_deg * 100) % 36000,
        fix["satellites"],
    )
