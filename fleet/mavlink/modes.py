"""Flight modes of ArduCopter, ArduRover, ArduSub and PX4: names, custom mode numbers, and
HEARTBEAT decoding.

A HEARTBEAT carries the flight mode in ``custom_mode`` (with MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
in ``base_mode``), and each autopilot encodes it its own way:

- ArduPilot: ``custom_mode`` is the vehicle's mode number; the numbers differ per firmware, so
  the table is picked by the HEARTBEAT's ``type`` (as pymavlink's ``mode_mapping_bynumber``
  does): ArduCopter for multicopters, ArduRover for ground rovers and boats (a boat is
  ArduRover with FRAME_CLASS=2), ArduSub for submarines. Every function takes that type
  (``mav_type``), a quadrotor by default.
- PX4: ``custom_mode`` is a union ``{uint16 reserved; uint8 main_mode; uint8 sub_mode}`` in
  little-endian order, i.e. ``main_mode << 16 | sub_mode << 24``. Sub-modes matter for AUTO
  (takeoff, loiter, mission, RTL, land) and POSCTL (orbit).

To command a mode, both take MAV_CMD_DO_SET_MODE with param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
ArduPilot reads the mode number from param2, PX4 the main mode from param2 and the sub-mode
from param3 (``set_mode_params``).
"""

from __future__ import annotations

from enum import Enum

from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER
from fleet.mavlink.wire import mavlink


class Autopilot(Enum):
    """The flight stack on the other end, from HEARTBEAT.autopilot."""

    ARDUPILOT = "ardupilot"
    PX4 = "px4"
    OTHER = "other"

    @classmethod
    def from_heartbeat(cls, autopilot: int) -> Autopilot:
        """MAV_AUTOPILOT_ARDUPILOTMEGA (3) and MAV_AUTOPILOT_PX4 (12); anything else is OTHER."""
        if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            return cls.ARDUPILOT
        if autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return cls.PX4
        return cls.OTHER


# ArduCopter's custom mode numbers (ArduCopter/mode.h, Mode::Number).
ARDUCOPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "DRIFT": 11,
    "SPORT": 13,
    "FLIP": 14,
    "AUTOTUNE": 15,
    "POSHOLD": 16,
    "BRAKE": 17,
    "THROW": 18,
    "AVOID_ADSB": 19,
    "GUIDED_NOGPS": 20,
    "SMART_RTL": 21,
    "FLOWHOLD": 22,
    "FOLLOW": 23,
    "ZIGZAG": 24,
    "SYSTEMID": 25,
    "AUTOROTATE": 26,
    "AUTO_RTL": 27,
    "TURTLE": 28,
}
ARDUCOPTER_NAMES: dict[int, str] = {number: name for name, number in ARDUCOPTER_MODES.items()}

# ArduRover's (Rover/mode.h, Mode::Number; 2 was a mode since removed), for rovers and boats.
ARDUROVER_MODES: dict[str, int] = {
    "MANUAL": 0,
    "ACRO": 1,
    "STEERING": 3,
    "HOLD": 4,
    "LOITER": 5,
    "FOLLOW": 6,
    "SIMPLE": 7,
    "DOCK": 8,
    "CIRCLE": 9,
    "AUTO": 10,
    "RTL": 11,
    "SMART_RTL": 12,
    "GUIDED": 15,
    "INITIALISING": 16,
}
# ArduSub's (ArduSub/defines.h, control_mode_t). ArduSub has no RTL and no LAND.
ARDUSUB_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "CIRCLE": 7,
    "SURFACE": 9,
    "POSHOLD": 16,
    "MANUAL": 19,
    "MOTOR_DETECT": 20,
    "SURFTRAK": 21,
}
ARDUROVER_NAMES: dict[int, str] = {number: name for name, number in ARDUROVER_MODES.items()}
ARDUSUB_NAMES: dict[int, str] = {number: name for name, number in ARDUSUB_MODES.items()}

# PX4 main modes (px4_custom_mode.h, PX4_CUSTOM_MAIN_MODE) and sub-modes.
PX4_MAIN_MANUAL = 1
PX4_MAIN_ALTCTL = 2
PX4_MAIN_POSCTL = 3
PX4_MAIN_AUTO = 4
PX4_MAIN_ACRO = 5
PX4_MAIN_OFFBOARD = 6
PX4_MAIN_STABILIZED = 7
PX4_MAIN_RATTITUDE = 8
PX4_AUTO_READY = 1
PX4_AUTO_TAKEOFF = 2
PX4_AUTO_LOITER = 3
PX4_AUTO_MISSION = 4
PX4_AUTO_RTL = 5
PX4_AUTO_LAND = 6
PX4_AUTO_FOLLOW_TARGET = 8
PX4_AUTO_PRECLAND = 9
PX4_POSCTL_ORBIT = 1

# Names as QGroundControl and pymavlink show them.
PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (PX4_MAIN_MANUAL, 0),
    "ALTCTL": (PX4_MAIN_ALTCTL, 0),
    "POSCTL": (PX4_MAIN_POSCTL, 0),
    "ORBIT": (PX4_MAIN_POSCTL, PX4_POSCTL_ORBIT),
    "AUTO.READY": (PX4_MAIN_AUTO, PX4_AUTO_READY),
    "AUTO.TAKEOFF": (PX4_MAIN_AUTO, PX4_AUTO_TAKEOFF),
    "AUTO.LOITER": (PX4_MAIN_AUTO, PX4_AUTO_LOITER),
    "AUTO.MISSION": (PX4_MAIN_AUTO, PX4_AUTO_MISSION),
    "AUTO.RTL": (PX4_MAIN_AUTO, PX4_AUTO_RTL),
    "AUTO.LAND": (PX4_MAIN_AUTO, PX4_AUTO_LAND),
    "AUTO.FOLLOW_TARGET": (PX4_MAIN_AUTO, PX4_AUTO_FOLLOW_TARGET),
    "AUTO.PRECLAND": (PX4_MAIN_AUTO, PX4_AUTO_PRECLAND),
    "ACRO": (PX4_MAIN_ACRO, 0),
    "OFFBOARD": (PX4_MAIN_OFFBOARD, 0),
    "STABILIZED": (PX4_MAIN_STABILIZED, 0),
    "RATTITUDE": (PX4_MAIN_RATTITUDE, 0),
}
PX4_NAMES: dict[tuple[int, int], str] = {modes: name for name, modes in PX4_MODES.items()}

# Airframes the driver flies (HEARTBEAT.type): multicopters and helicopters, rovers, boats and
# submarines.
COPTER_TYPES = frozenset(
    {
        mavlink.MAV_TYPE_QUADROTOR,
        mavlink.MAV_TYPE_HEXAROTOR,
        mavlink.MAV_TYPE_OCTOROTOR,
        mavlink.MAV_TYPE_TRICOPTER,
        mavlink.MAV_TYPE_HELICOPTER,
        mavlink.MAV_TYPE_COAXIAL,
        mavlink.MAV_TYPE_DECAROTOR,
        mavlink.MAV_TYPE_DODECAROTOR,
    }
)
ROVER_TYPES = frozenset({mavlink.MAV_TYPE_GROUND_ROVER})
BOAT_TYPES = frozenset({mavlink.MAV_TYPE_SURFACE_BOAT})
SUB_TYPES = frozenset({mavlink.MAV_TYPE_SUBMARINE})

# The vehicle kind (``fleet.kinds``) each airframe type is, and how people name it.
KIND_OF_TYPE: dict[int, str] = {
    **{t: AERIAL for t in COPTER_TYPES},
    **{t: GROUND for t in ROVER_TYPES},
    **{t: SURFACE for t in BOAT_TYPES},
    **{t: UNDERWATER for t in SUB_TYPES},
}
KIND_WORDS: dict[str, str] = {
    AERIAL: "a copter",
    GROUND: "a ground rover",
    SURFACE: "a surface boat",
    UNDERWATER: "a submarine",
}


def ardupilot_modes(mav_type: int) -> dict[str, int]:
    """The ArduPilot mode table of an airframe type: ArduRover's for rovers and boats,
    ArduSub's for submarines, ArduCopter's for anything else."""
    if mav_type in ROVER_TYPES or mav_type in BOAT_TYPES:
        return ARDUROVER_MODES
    if mav_type in SUB_TYPES:
        return ARDUSUB_MODES
    return ARDUCOPTER_MODES


def ardupilot_names(mav_type: int) -> dict[int, str]:
    """Mode names by number for an airframe type (the inverse of ``ardupilot_modes``)."""
    if mav_type in ROVER_TYPES or mav_type in BOAT_TYPES:
        return ARDUROVER_NAMES
    if mav_type in SUB_TYPES:
        return ARDUSUB_NAMES
    return ARDUCOPTER_NAMES


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4's HEARTBEAT.custom_mode for a main mode and sub-mode (bytes 2 and 3 of the union)."""
    return (main_mode & 0xFF) << 16 | (sub_mode & 0xFF) << 24


def px4_split(custom_mode: int) -> tuple[int, int]:
    """(main_mode, sub_mode) of a PX4 HEARTBEAT.custom_mode."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def mode_name(
    autopilot: Autopilot, custom_mode: int, mav_type: int = mavlink.MAV_TYPE_QUADROTOR
) -> str:
    """The name of the mode a heartbeat reports, e.g. "GUIDED" or "AUTO.LOITER"; ArduPilot's
    number is read in the table of the heartbeat's ``mav_type`` (15 is GUIDED on a rover).

    An unknown number gives "MODE(n)" (ArduPilot) or "MODE(main.sub)" (PX4), never an error:
    a vehicle in a mode this table lacks must not break the link.
    """
    if autopilot is Autopilot.PX4:
        main, sub = px4_split(custom_mode)
        name = PX4_NAMES.get((main, sub)) or PX4_NAMES.get((main, 0))
        return name if name is not None else f"MODE({main}.{sub})"
    return ardupilot_names(mav_type).get(custom_mode, f"MODE({custom_mode})")


def custom_mode_of(
    autopilot: Autopilot, name: str, mav_type: int = mavlink.MAV_TYPE_QUADROTOR
) -> int:
    """The HEARTBEAT.custom_mode a mode name shows as (ArduPilot: in the table of
    ``mav_type``). Raises KeyError for an unknown name."""
    if autopilot is Autopilot.PX4:
        return px4_custom_mode(*PX4_MODES[name])
    return ardupilot_modes(mav_type)[name]


def set_mode_params(
    autopilot: Autopilot, name: str, mav_type: int = mavlink.MAV_TYPE_QUADROTOR
) -> tuple[float, float, float]:
    """param1..param3 of MAV_CMD_DO_SET_MODE for a mode name (ArduPilot: in the table of
    ``mav_type``). Raises KeyError if unknown."""
    flag = float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    if autopilot is Autopilot.PX4:
        main, sub = PX4_MODES[name]
        return flag, float(main), float(sub)
    return flag, float(ardupilot_modes(mav_type)[name]), 0.0


def same_mode(autopilot: Autopilot, reported: int, wanted: int) -> bool:
    """Whether a heartbeat's custom_mode is the wanted one.

    PX4 reports AUTO's sub-mode but not always POSCTL's, so for main modes without a sub-mode
    only the main mode is compared.
    """
    if autopilot is Autopilot.PX4:
        main, sub = px4_split(reported)
        want_main, want_sub = px4_split(wanted)
        return main == want_main and ((want_sub == 0 and main != PX4_MAIN_AUTO) or sub == want_sub)
    return reported == wanted
