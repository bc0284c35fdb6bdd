"""Where a guided target or a mission item points, in the frames ArduCopter flies.

Positions are the platform's: degrees and metres above ground (the world is flat at the
depot's ground, ``ground_amsl_m`` above mean sea level).
"""

from __future__ import annotations

from fleet.geo import Position, offset
from fleet.mavlink.wire import mavlink

RELATIVE_FRAMES = frozenset(
    {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
)
AMSL_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT})
TERRAIN_FRAMES = frozenset(
    {mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}
)
GLOBAL_FRAMES = RELATIVE_FRAMES | AMSL_FRAMES | TERRAIN_FRAMES


class TargetRefused(ValueError):
    """A target the vehicle does not fly; ``unsupported_frame`` says whether the frame is why."""

    def __init__(self, message: str, *, unsupported_frame: bool = False) -> None:
        super().__init__(message)
        self.unsupported_frame = unsupported_frame


def above_ground(frame: int, alt: float, *, home: Position, ground_amsl_m: float) -> float:
    """A global frame's altitude as metres above ground. Raises TargetRefused for a frame that
    is not global."""
    if frame in RELATIVE_FRAMES:
        return home.alt + alt
    if frame in AMSL_FRAMES:
        return alt - ground_amsl_m
    if frame in TERRAIN_FRAMES:
        return alt  # a flat world: above terrain is above ground
    raise TargetRefused(f"frame {frame} not supported", unsupported_frame=True)


def global_target(
    frame: int, lat: float, lng: float, alt: float, *, home: Position, ground_amsl_m: float
) -> Position:
    """The position a global-frame target (degrees, altitude in ``frame``) points at.

    Raises TargetRefused for a frame that is not global or a position off the globe.
    """
    height = above_ground(frame, alt, home=home, ground_amsl_m=ground_amsl_m)
    try:
        return Position(lat, lng, height)
    except ValueError as exc:
        raise TargetRefused(str(exc)) from None


def local_target(
    frame: int, north: float, east: float, down: float, *, home: Position, here: Position
) -> Position:
    """The position a SET_POSITION_TARGET_LOCAL_NED points at: MAV_FRAME_LOCAL_NED is metres
    from home (ArduCopter's EKF origin), MAV_FRAME_LOCAL_OFFSET_NED metres from where the
    vehicle is. Raises TargetRefused for any other frame (the body frames need the attitude)."""
    if frame == mavlink.MAV_FRAME_LOCAL_NED:
        origin = home
    elif frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED:
        origin = here
    else:
        raise TargetRefused(f"frame {frame} not supported", unsupported_frame=True)
    return offset(origin, north_m=north, east_m=east, up_m=-down)
