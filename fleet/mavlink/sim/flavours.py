"""What differs between the simulated autopilots: ArduCopter and PX4 (copters), ArduRover (a
rover, and a boat: ArduRover with FRAME_CLASS=2) and ArduSub (a submarine): the airframe type
in HEARTBEAT, modes, take-off, parameter names and encodings, what their failsafes do.

``flavour_of(autopilot, frame)`` picks one: the frames are ``FRAMES`` (copter, rover, boat,
sub); PX4 is simulated as a copter only."""

from __future__ import annotations

from dataclasses import dataclass, replace

from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER
from fleet.mavlink import params as param_codec
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.wire import mavlink
from fleet.simulation.vehicle import VehicleSpec


@dataclass(frozen=True)
class Flavour:
    """How one autopilot behaves where ArduCopter, PX4, ArduRover and ArduSub differ."""

    autopilot: Autopilot
    heartbeat_autopilot: int
    initial_mode: str
    armable: frozenset[str]  # modes arming is allowed in
    hold: frozenset[str]  # modes that hold position in the air (or stop: a rover's HOLD)
    follows_targets: str  # the mode that flies SET_POSITION_TARGET_GLOBAL_INT
    rtl: str | None  # the mode that goes home (None: ArduSub has none)
    land: str  # the mode that ends the trip where it is: LAND, a rover's HOLD, SURFACE
    mission: str  # the mode that flies the uploaded mission
    mission_first_seq: int  # ArduPilot keeps home in item 0 and starts at 1
    takeoff_in: frozenset[str] | None  # modes NAV_TAKEOFF is accepted in (None: any)
    takeoff_mode: str | None  # the mode NAV_TAKEOFF switches to
    after_takeoff: str | None  # the mode the vehicle is in once up
    takeoff_alt_amsl: bool  # NAV_TAKEOFF param7: AMSL (PX4) or relative to home (ArduPilot)
    refusal_prefix: str
    bytewise_params: bool
    setpoint_stream: bool  # the follow mode needs a live setpoint stream (PX4 offboard)
    speed_params: tuple[tuple[str, str, float], ...]  # (param, spec field, unit in m/s)
    rtl_alt_param: tuple[str, float] | None  # (param, unit in metres); None: not aerial
    disarm_delay_param: str | None  # None: it never disarms by itself on the ground
    # The GCS (data link) failsafe: the parameter that turns it on (0: off) and its timeout.
    gcs_failsafe_params: tuple[str, str]
    frame: str = "copter"  # one of FRAMES
    mav_type: int = mavlink.MAV_TYPE_QUADROTOR  # HEARTBEAT.type
    kind: str = AERIAL  # how it moves (``fleet.kinds``, the simulator's VehicleSpec.kind)
    # Commands it answers UNSUPPORTED (ArduRover and ArduSub neither take off nor land).
    unsupported: frozenset[int] = frozenset()

    @property
    def takes_off(self) -> bool:
        """An aircraft: it takes off before it goes anywhere, and lands when it is done."""
        return self.kind == AERIAL


ARDUCOPTER = Flavour(
    autopilot=Autopilot.ARDUPILOT,
    heartbeat_autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    initial_mode="STABILIZE",
    armable=frozenset({"STABILIZE", "ALT_HOLD", "GUIDED", "LOITER", "POSHOLD"}),
    hold=frozenset({"STABILIZE", "ALT_HOLD", "GUIDED", "LOITER", "POSHOLD", "BRAKE"}),
    follows_targets="GUIDED",
    rtl="RTL",
    land="LAND",
    mission="AUTO",
    mission_first_seq=1,
    takeoff_in=frozenset({"GUIDED"}),
    takeoff_mode=None,
    after_takeoff=None,
    takeoff_alt_amsl=False,
    refusal_prefix="PreArm: ",
    bytewise_params=False,
    setpoint_stream=False,
    speed_params=(
        ("WPNAV_SPEED", "max_speed_mps", 0.01),
        ("WPNAV_SPEED_UP", "climb_rate_mps", 0.01),
    ),
    rtl_alt_param=("RTL_ALT", 0.01),
    disarm_delay_param="DISARM_DELAY",
    gcs_failsafe_params=("FS_GCS_ENABLE", "FS_GCS_TIMEOUT"),
)
PX4 = Flavour(
    autopilot=Autopilot.PX4,
    heartbeat_autopilot=mavlink.MAV_AUTOPILOT_PX4,
    initial_mode="AUTO.LOITER",
    armable=frozenset({"MANUAL", "ALTCTL", "POSCTL", "AUTO.LOITER", "OFFBOARD"}),
    hold=frozenset({"MANUAL", "ALTCTL", "POSCTL", "AUTO.LOITER", "STABILIZED"}),
    follows_targets="OFFBOARD",
    rtl="AUTO.RTL",
    land="AUTO.LAND",
    mission="AUTO.MISSION",
    mission_first_seq=0,
    takeoff_in=None,
    takeoff_mode="AUTO.TAKEOFF",
    after_takeoff="AUTO.LOITER",
    takeoff_alt_amsl=True,
    refusal_prefix="Preflight Fail: ",
    bytewise_params=True,
    setpoint_stream=True,
    speed_params=(
        ("MPC_XY_CRUISE", "max_speed_mps", 1.0),
        ("MPC_Z_V_AUTO_UP", "climb_rate_mps", 1.0),
    ),
    rtl_alt_param=("RTL_RETURN_ALT", 1.0),
    disarm_delay_param="COM_DISARM_PRFLT",
    gcs_failsafe_params=("NAV_DLL_ACT", "COM_DL_LOSS_T"),
)
_NO_FLIGHT = frozenset({mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_LAND})
ARDUROVER = Flavour(
    autopilot=Autopilot.ARDUPILOT,
    heartbeat_autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    initial_mode="MANUAL",
    # ArduRover arms in any mode but AUTO, RTL and SMART_RTL (Mode::allows_arming).
    armable=frozenset({"MANUAL", "ACRO", "STEERING", "HOLD", "LOITER", "GUIDED", "SIMPLE"}),
    hold=frozenset({"MANUAL", "ACRO", "STEERING", "HOLD", "LOITER", "SIMPLE"}),
    follows_targets="GUIDED",
    rtl="RTL",
    land="HOLD",
    mission="AUTO",
    mission_first_seq=1,
    takeoff_in=None,
    takeoff_mode=None,
    after_takeoff=None,
    takeoff_alt_amsl=False,
    refusal_prefix="PreArm: ",
    bytewise_params=False,
    setpoint_stream=False,
    speed_params=(("WP_SPEED", "max_speed_mps", 1.0), ("CRUISE_SPEED", "max_speed_mps", 1.0)),
    rtl_alt_param=None,
    disarm_delay_param=None,
    # ArduRover's GCS failsafe acts after FS_TIMEOUT with FS_ACTION (RTL, HOLD, ...).
    gcs_failsafe_params=("FS_GCS_ENABLE", "FS_TIMEOUT"),
    frame="rover",
    mav_type=mavlink.MAV_TYPE_GROUND_ROVER,
    kind=GROUND,
    unsupported=_NO_FLIGHT,
)
ARDUBOAT = replace(ARDUROVER, frame="boat", mav_type=mavlink.MAV_TYPE_SURFACE_BOAT, kind=SURFACE)
ARDUSUB = replace(
    ARDUROVER,
    armable=frozenset({"MANUAL", "STABILIZE", "ACRO", "ALT_HOLD", "POSHOLD", "GUIDED"}),
    hold=frozenset({"MANUAL", "STABILIZE", "ACRO", "ALT_HOLD", "POSHOLD", "SURFTRAK"}),
    rtl=None,
    land="SURFACE",
    speed_params=(
        ("WPNAV_SPEED", "max_speed_mps", 0.01),
        ("WPNAV_SPEED_UP", "climb_rate_mps", 0.01),
        ("WPNAV_SPEED_DN", "dive_rate_mps", 0.01),
    ),
    # ArduSub's FS_GCS_ENABLE says what to do: 1 warn, 2 disarm, 3 depth hold, 4 surface.
    gcs_failsafe_params=("FS_GCS_ENABLE", "FS_GCS_TIMEOUT"),
    frame="sub",
    mav_type=mavlink.MAV_TYPE_SUBMARINE,
    kind=UNDERWATER,
    unsupported=_NO_FLIGHT | {mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH},
)
FLAVOURS = {"ardupilot": ARDUCOPTER, "px4": PX4}
FRAMES = ("copter", "rover", "boat", "sub")
_ARDUPILOT_FRAMES = {"copter": ARDUCOPTER, "rover": ARDUROVER, "boat": ARDUBOAT, "sub": ARDUSUB}
# The frame that simulates a vehicle of each kind (``manage.py mavsim``'s default).
FRAME_OF_KIND = {AERIAL: "copter", GROUND: "rover", SURFACE: "boat", UNDERWATER: "sub"}


def flavour_of(autopilot: str, frame: str = "copter") -> Flavour:
    """The simulated autopilot of a frame ("copter", "rover", "boat", "sub") on an autopilot
    ("ardupilot", "px4"). Raises ValueError naming what there is."""
    if autopilot not in FLAVOURS:
        raise ValueError(f"autopilot must be one of {sorted(FLAVOURS)}, got {autopilot!r}")
    if frame not in FRAMES:
        raise ValueError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    if autopilot == "px4":
        if frame != "copter":
            raise ValueError(f"PX4 is simulated as a copter only, not as a {frame}")
        return PX4
    return _ARDUPILOT_FRAMES[frame]


@dataclass
class Param:
    """A parameter's value and MAV_PARAM_TYPE."""

    value: float
    type: int


def initial_params(
    flavour: Flavour, spec: VehicleSpec, *, system_id: int, battery_capacity_mah: int
) -> dict[str, Param]:
    """The parameters a simulated vehicle of this flavour starts with, by name (in the order
    PARAM_REQUEST_LIST streams them)."""
    real = param_codec.REAL32
    int8 = int(mavlink.MAV_PARAM_TYPE_INT8)
    int16 = int(mavlink.MAV_PARAM_TYPE_INT16)
    int32 = int(mavlink.MAV_PARAM_TYPE_INT32)
    if flavour.autopilot is Autopilot.PX4:
        return {
            "GF_ACTION": Param(2, int32),
            "GF_MAX_HOR_DIST": Param(0.0, real),
            "GF_MAX_VER_DIST": Param(0.0, real),
            "BAT1_CAPACITY": Param(float(battery_capacity_mah), real),
            "MPC_XY_CRUISE": Param(spec.max_speed_mps, real),
            "MPC_Z_V_AUTO_UP": Param(spec.climb_rate_mps, real),
            "MPC_Z_V_AUTO_DN": Param(spec.climb_rate_mps, real),
            "MIS_TAKEOFF_ALT": Param(spec.takeoff_alt_m, real),
            "RTL_RETURN_ALT": Param(spec.takeoff_alt_m, real),
            "COM_DISARM_PRFLT": Param(10.0, real),
            "MAV_SYS_ID": Param(float(system_id), int32),
            "NAV_DLL_ACT": Param(0, int32),  # data link loss: disabled, as PX4 ships
            "COM_DL_LOSS_T": Param(10.0, real),
        }
    if flavour.kind in (GROUND, SURFACE):
        return {
            "FENCE_ENABLE": Param(0, int8),
            "FENCE_TYPE": Param(6, int8),  # circle and polygon (a rover has no altitude)
            "FENCE_ACTION": Param(1, int8),  # 0 report, 1 RTL, 2 HOLD, ...
            "FENCE_MARGIN": Param(2.0, real),
            "FENCE_RADIUS": Param(300.0, real),
            "BATT_CAPACITY": Param(float(battery_capacity_mah), int32),
            "WP_SPEED": Param(spec.max_speed_mps, real),  # m/s
            "CRUISE_SPEED": Param(spec.max_speed_mps, real),
            "WP_RADIUS": Param(2.0, real),
            "FRAME_CLASS": Param(2 if flavour.kind == SURFACE else 1, int8),  # 1 rover, 2 boat
            "SYSID_THISMAV": Param(float(system_id), int16),
            "FS_GCS_ENABLE": Param(0, int8),  # off, as ArduRover ships
            "FS_ACTION": Param(2, int8),  # 0 nothing, 1 RTL, 2 HOLD (ArduRover's default)
            "FS_TIMEOUT": Param(1.5, real),
        }
    if flavour.kind == UNDERWATER:
        dive = spec.climb_rate_mps if spec.dive_rate_mps is None else spec.dive_rate_mps
        return {
            "FENCE_ENABLE": Param(0, int8),
            "FENCE_TYPE": Param(6, int8),
            "FENCE_ACTION": Param(0, int8),  # ArduSub's fence only reports
            "FENCE_MARGIN": Param(2.0, real),
            "FENCE_RADIUS": Param(300.0, real),
            "BATT_CAPACITY": Param(float(battery_capacity_mah), int32),
            "WPNAV_SPEED": Param(spec.max_speed_mps * 100, real),
            "WPNAV_SPEED_UP": Param(spec.climb_rate_mps * 100, real),
            "WPNAV_SPEED_DN": Param(dive * 100, real),
            "SYSID_THISMAV": Param(float(system_id), int16),
            "FS_GCS_ENABLE": Param(0, int8),  # 0 off, 1 warn, 2 disarm, 3 depth hold, 4 surface
            "FS_GCS_TIMEOUT": Param(5.0, real),
        }
    return {
        "FENCE_ENABLE": Param(0, int8),
        "FENCE_TYPE": Param(7, int8),  # max altitude, circle and polygon
        "FENCE_ACTION": Param(1, int8),  # RTL or land
        "FENCE_ALT_MAX": Param(100.0, real),
        "FENCE_ALT_MIN": Param(-10.0, real),
        "FENCE_MARGIN": Param(2.0, real),
        "FENCE_RADIUS": Param(300.0, real),
        "BATT_CAPACITY": Param(float(battery_capacity_mah), int32),
        "WPNAV_SPEED": Param(spec.max_speed_mps * 100, real),
        "WPNAV_SPEED_UP": Param(spec.climb_rate_mps * 100, real),
        "WPNAV_SPEED_DN": Param(spec.climb_rate_mps * 100, real),
        "RTL_ALT": Param(round(spec.takeoff_alt_m * 100), int32),
        "DISARM_DELAY": Param(10, int8),
        "SYSID_THISMAV": Param(float(system_id), int16),
        "FS_GCS_ENABLE": Param(0, int8),  # off, as ArduCopter ships
        "FS_GCS_TIMEOUT": Param(5.0, real),
    }
