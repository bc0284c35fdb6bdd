"""Pure simulation core of the fleet: kinematic vehicles, sensor fields, camera images, map tiles.

No Django here: time and randomness are injected (times in seconds on the caller's clock, an
integer seed), so the same inputs always give the same outputs.
"""

from fleet.simulation.camera import render_camera
from fleet.simulation.sensors import (
    CAMERA_FORMATS,
    CAMERA_VIEWS,
    SCALAR_QUANTITIES,
    SENSOR_KINDS,
    CameraSettings,
    SensorField,
    SensorSpec,
    camera_settings,
)
from fleet.simulation.tiles import render_tile
from fleet.simulation.vehicle import Leg, SimVehicle, VehicleSpec
from fleet.simulation.world import PLATFORM_WORLD_SEED

__all__ = [
    "CAMERA_FORMATS",
    "CAMERA_VIEWS",
    "PLATFORM_WORLD_SEED",
    "SCALAR_QUANTITIES",
    "SENSOR_KINDS",
    "CameraSettings",
    "Leg",
    "SensorField",
    "SensorSpec",
    "SimVehicle",
    "VehicleSpec",
    "camera_settings",
    "render_camera",
    "render_tile",
]
