"""Simulated sensors: plausible, spatially structured readings of a seeded world.

Pure Python + numpy (no Django). ``SensorField(seed).sample(sensor, position, time_s)`` returns
the kind-specific fields of one reading as a JSON-able dict; the same seed, sensor, position and
time always give the same dict, another seed gives another world.

Reading shapes (what ``sample`` returns):

- scalar: ``{"value": float, "unit": str}``; ``params["quantity"]`` picks the quantity:

  ============  ====  ==========================================================================
  quantity      unit  model
  ============  ====  ==========================================================================
  co2           ppm   ~415 background with seeded plumes up to a few hundred ppm, weaker aloft
  temperature   °C    ~12-18 at ground, smooth spatial variation, daily drift, -6.5 °C/km
  nox           ppb   10-80, higher near roads and plumes
  pressure      hPa   ISA barometric formula of the altitude, plus a small spatial gradient
  altitude      m     position altitude plus up to ±0.5 m noise
  battery       %     100 * battery_fraction (100 when not given)
  ============  ====  ==========================================================================

  The value is rounded to 2 decimals. ``sensor.unit`` is used as the label when set (no unit
  conversion is done); otherwise the unit above.
- gps: ``{"lat", "lng", "alt", "satellites", "hdop"}``; the fix is within a few metres of the
  true position (under 3.2 m horizontally, 2 m vertically).
- camera: ``{"width", "height", "format"}``; the image comes from ``render_camera``.

Altitudes are metres above ground; times are seconds on the caller's clock (time of day for the
temperature drift is ``time_s mod 86400``).
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fleet.geo import Position, offset
from fleet.simulation.world import (
    FloatArray,
    derive_key,
    fbm,
    hash_units,
    lattice_unit,
    local_xy,
    road_distance_m,
)

KIND_SCALAR = "scalar"
KIND_GPS = "gps"
KIND_CAMERA = "camera"
SENSOR_KINDS = (KIND_SCALAR, KIND_GPS, KIND_CAMERA)

# Default unit per scalar quantity.
SCALAR_QUANTITIES: Mapping[str, str] = {
    "co2": "ppm",
    "temperature": "°C",
    "nox": "ppb",
    "pressure": "hPa",
    "altitude": "m",
    "battery": "%",
}

CAMERA_FORMATS = ("png", "jpeg")
CAMERA_VIEWS = ("front", "belly", "fpv")
MAX_IMAGE_SIDE_PX = 4096

_DAY_S = 86_400.0
_PLUME_CELL_M = 1500.0
_NEIGHBOUR_DX = np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1], dtype=np.int64)
_NEIGHBOUR_DY = np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1], dtype=np.int64)


@dataclass(frozen=True)
class SensorSpec:
    """One sensor as the simulator sees it: an SDC entry's name, kind, unit and parameters.

    ``kind`` is "scalar", "gps" or "camera". Scalar: ``params["quantity"]`` in
    ``SCALAR_QUANTITIES``. Camera: ``params`` may hold ``width``, ``height`` (pixels, default
    640x480), ``format`` ("png" or "jpeg", default "png") and ``view`` ("front", "belly" or
    "fpv", default "front"). Validated when used, not when built.
    """

    name: str
    kind: str
    unit: str = ""
    params: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class CameraSettings:
    """The validated image parameters of a camera sensor."""

    width: int
    height: int
    format: str
    view: str


def camera_settings(sensor: SensorSpec) -> CameraSettings:
    """Read and check a camera sensor's params (defaults 640x480, "png", "front").

    Raises ValueError naming the sensor and the bad parameter if the kind is not "camera", a
    size is not an integer in 1..4096, or the format or view is unknown ("jpg" means "jpeg").
    """
    if sensor.kind != KIND_CAMERA:
        raise ValueError(f"sensor {sensor.name!r} is of kind {sensor.kind!r}, not a camera")
    params = sensor.params
    sizes: list[int] = []
    for key, default in (("width", 640), ("height", 480)):
        value = params.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"camera {sensor.name!r}: {key} must be an integer, got {value!r}")
        if not 1 <= value <= MAX_IMAGE_SIDE_PX:
            raise ValueError(
                f"camera {sensor.name!r}: {key} must be in 1..{MAX_IMAGE_SIDE_PX}, got {value}"
            )
        sizes.append(value)
    fmt = str(params.get("format", "png")).lower()
    if fmt == "jpg":
        fmt = "jpeg"
    if fmt not in CAMERA_FORMATS:
        raise ValueError(
            f"camera {sensor.name!r}: unknown image format {params.get('format')!r} "
            f"(expected one of {', '.join(CAMERA_FORMATS)})"
        )
    view = str(params.get("view", "front")).lower()
    if view not in CAMERA_VIEWS:
        raise ValueError(
            f"camera {sensor.name!r}: unknown view {params.get('view')!r} "
            f"(expected one of {', '.join(CAMERA_VIEWS)})"
        )
    return CameraSettings(width=sizes[0], height=sizes[1], format=fmt, view=view)


def _arrays(position: Position) -> tuple[FloatArray, FloatArray]:
    x, y = local_xy(position.lat, position.lng)
    return np.array([x], dtype=np.float64), np.array([y], dtype=np.float64)


class SensorField:
    """All simulated sensor readings of one seeded world.

    ``seed`` (an int) fixes the world: plume places, temperature and pressure patterns, noise.
    Cheap to build; holds no mutable state, so one instance may be shared.
    """

    def __init__(self, seed: int) -> None:
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        self.seed = seed
        rng = random.Random(seed)
        self._temp_base_c = 15.0 + rng.uniform(-1.0, 1.0)
        self._temp_phase = rng.uniform(0.0, 2.0 * math.pi)
        self._pressure_base_hpa = 1013.25 + rng.uniform(-8.0, 8.0)
        self._pressure_phase = rng.uniform(0.0, 2.0 * math.pi)
        wind_rad = rng.uniform(0.0, 2.0 * math.pi)
        self._wind_cos = math.cos(wind_rad)
        self._wind_sin = math.sin(wind_rad)
        self._keys = {
            name: derive_key(seed, name)
            for name in (
                "co2-bg",
                "co2-turb",
                "temp-large",
                "temp-small",
                "nox",
                "pressure-large",
                "pressure-small",
            )
        }
        plume_names = ("plume-on", "plume-x", "plume-y", "plume-amp", "plume-width", "plume-phase")
        self._plume_keys = np.array(
            [derive_key(seed, name) for name in plume_names], dtype=np.uint64
        )

    def sample(
        self,
        sensor: SensorSpec,
        position: Position,
        time_s: float,
        *,
        battery_fraction: float | None = None,
    ) -> dict[str, Any]:
        """The kind-specific fields of one reading of ``sensor`` at ``position`` and ``time_s``.

        ``battery_fraction`` (0..1, clamped) feeds the "battery" quantity. Returns the dict
        described in the module docstring. Raises ValueError for an unknown kind or quantity (the
        message names it), bad camera params, or a time or battery fraction that is not finite.
        """
        if not math.isfinite(time_s):
            raise ValueError(f"time_s must be a finite number, got {time_s!r}")
        if sensor.kind == KIND_SCALAR:
            quantity = str(sensor.params.get("quantity", "")).lower()
            if quantity not in SCALAR_QUANTITIES:
                raise ValueError(
                    f"sensor {sensor.name!r}: unknown scalar quantity "
                    f"{sensor.params.get('quantity')!r} (expected one of "
                    f"{', '.join(SCALAR_QUANTITIES)})"
                )
            value = self.scalar_value(
                quantity, position, time_s, sensor.name, battery_fraction=battery_fraction
            )
            return {"value": value, "unit": sensor.unit or SCALAR_QUANTITIES[quantity]}
        if sensor.kind == KIND_GPS:
            return self._gps(sensor.name, position, time_s)
        if sensor.kind == KIND_CAMERA:
            settings = camera_settings(sensor)
            return {"width": settings.width, "height": settings.height, "format": settings.format}
        raise ValueError(
            f"sensor {sensor.name!r}: unknown sensor kind {sensor.kind!r} "
            f"(expected one of {', '.join(SENSOR_KINDS)})"
        )

    def scalar_value(
        self,
        quantity: str,
        position: Position,
        time_s: float,
        sensor_name: str = "",
        *,
        battery_fraction: float | None = None,
    ) -> float:
        """One scalar quantity (a key of ``SCALAR_QUANTITIES``), rounded to 2 decimals.

        ``sensor_name`` only decorrelates the measurement noise of two sensors of the same
        quantity. Raises ValueError for an unknown quantity or a non-finite battery fraction.
        """
        noise = hash_units(
            self.seed,
            sensor_name,
            quantity,
            round(position.lat, 7),
            round(position.lng, 7),
            round(position.alt, 2),
            round(time_s, 3),
        )
        # Triangular noise in [-1, 1): readings scatter around the field, rarely at the edges.
        jitter = noise[0] + noise[1] - 1.0
        if quantity == "co2":
            value = self._co2_ppm(position, time_s) + 0.8 * jitter
        elif quantity == "temperature":
            value = self._temperature_c(position, time_s) + 0.05 * jitter
        elif quantity == "nox":
            value = min(80.0, max(10.0, self._nox_ppb(position, time_s) + 0.3 * jitter))
        elif quantity == "pressure":
            value = self._pressure_hpa(position, time_s) + 0.02 * jitter
        elif quantity == "altitude":
            value = position.alt + 0.5 * jitter
        elif quantity == "battery":
            if battery_fraction is None:
                value = 100.0
            elif not math.isfinite(battery_fraction):
                raise ValueError(f"battery_fraction must be finite, got {battery_fraction!r}")
            else:
                value = 100.0 * min(1.0, max(0.0, battery_fraction))
        else:
            raise ValueError(
                f"unknown scalar quantity {quantity!r} "
                f"(expected one of {', '.join(SCALAR_QUANTITIES)})"
            )
        return round(float(value), 2)

    # Fields (noise-free)

    def _plumes_ppm(self, x: FloatArray, y: FloatArray, time_s: float) -> FloatArray:
        """Sum of elongated Gaussian plumes, at most one per 1.5 km lattice cell."""
        # Plumes are narrower than a cell, so the 3x3 neighbourhood holds every plume that
        # contributes more than ~1e-6 ppm: no visible seams at cell borders. The nine cells
        # are a trailing axis, evaluated in one pass.
        ix = np.floor(x / _PLUME_CELL_M).astype(np.int64)[..., None] + _NEIGHBOUR_DX
        iy = np.floor(y / _PLUME_CELL_M).astype(np.int64)[..., None] + _NEIGHBOUR_DY
        keys = self._plume_keys.reshape(-1, *(1,) * ix.ndim)
        u = lattice_unit(ix[None], iy[None], keys)
        present, ux, uy, u_amp, u_width, u_phase = u
        amplitude = 60.0 + 340.0 * u_amp**2
        # Sources breathe slowly (period 1.5 h), each on its own phase.
        amplitude *= 1.0 + 0.25 * np.sin(2.0 * math.pi * (time_s / 5400.0 + u_phase))
        across_m = 50.0 + 70.0 * u_width
        ex = x[..., None] - (ix + ux) * _PLUME_CELL_M
        ey = y[..., None] - (iy + uy) * _PLUME_CELL_M
        along = ex * self._wind_cos + ey * self._wind_sin
        side = ey * self._wind_cos - ex * self._wind_sin
        z = (along / (2.0 * across_m)) ** 2 + (side / across_m) ** 2
        plumes = np.where(present < 0.7, amplitude * np.exp(-0.5 * z), 0.0)
        total: FloatArray = plumes.sum(axis=-1)
        return total

    def _co2_ppm(self, position: Position, time_s: float) -> float:
        x, y = _arrays(position)
        keys = self._keys
        background = 415.0 + 6.0 * fbm(x, y, keys["co2-bg"], 2000.0, 4)
        turbulence = 1.0 + 0.2 * fbm(x, y, keys["co2-turb"], 40.0, 2)
        plume = self._plumes_ppm(x, y, time_s) * turbulence
        alt = max(0.0, position.alt)
        # Sources are on the ground: plumes thin out aloft, the background barely changes.
        value = background - 0.01 * alt + plume * math.exp(-alt / 150.0)
        return float(value[0])

    def _temperature_c(self, position: Position, time_s: float) -> float:
        x, y = _arrays(position)
        keys = self._keys
        spatial = 2.2 * fbm(x, y, keys["temp-large"], 2500.0, 3) + 0.6 * fbm(
            x, y, keys["temp-small"], 150.0, 2
        )
        daily = 1.5 * math.sin(2.0 * math.pi * time_s / _DAY_S + self._temp_phase)
        lapse = -0.0065 * position.alt
        return float(self._temp_base_c + spatial[0] + daily + lapse)

    def _nox_ppb(self, position: Position, time_s: float) -> float:
        x, y = _arrays(position)
        background = 18.0 + 24.0 * (0.5 + 0.5 * fbm(x, y, self._keys["nox"], 1800.0, 3))
        traffic = 28.0 * np.exp(-((road_distance_m(x, y, self.seed) / 70.0) ** 2))
        combustion = 0.06 * self._plumes_ppm(x, y, time_s)
        excess = (background - 10.0 + traffic + combustion) * math.exp(
            -max(0.0, position.alt) / 300.0
        )
        return float(10.0 + excess[0])

    def _pressure_hpa(self, position: Position, time_s: float) -> float:
        x, y = _arrays(position)
        keys = self._keys
        sea_level = (
            self._pressure_base_hpa
            + 1.5 * fbm(x, y, keys["pressure-large"], 40_000.0, 2)
            + 0.4 * fbm(x, y, keys["pressure-small"], 3000.0, 2)
            + 0.4 * math.sin(2.0 * math.pi * time_s / (_DAY_S / 2.0) + self._pressure_phase)
        )
        # ISA troposphere; altitude clamped so absurd inputs cannot leave the formula's domain.
        alt = min(max(position.alt, -500.0), 11_000.0)
        return float(sea_level[0] * (1.0 - 2.25577e-5 * alt) ** 5.25588)

    def _gps(self, sensor_name: str, position: Position, time_s: float) -> dict[str, Any]:
        u = hash_units(
            self.seed,
            sensor_name,
            "gps",
            round(position.lat, 6),
            round(position.lng, 6),
            round(position.alt, 1),
            round(time_s),
        )
        hdop = round(0.6 + 0.9 * u[0], 2)
        satellites = 14 - int(u[0] * 7.999)
        north, east, up = (2.0 * v - 1.0 for v in (u[1], u[2], u[3]))
        # Error grows with HDOP: at most 1.5 * 1.5 m per axis, 3 m vertically.
        fix = offset(position, north_m=1.5 * hdop * north, east_m=1.5 * hdop * east, up_m=2.0 * up)
        return {
            "lat": round(fix.lat, 7),
            "lng": round(fix.lng, 7),
            "alt": round(fix.alt, 2),
            "satellites": satellites,
            "hdop": hdop,
        }
