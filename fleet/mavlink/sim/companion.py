"""The simulated field's readings at the vehicle, over MAVLink.

``FieldSensors`` samples ``fleet.simulation.SensorField`` with the default device catalog's
scalar sensors (the same ``SensorSpec`` objects the platform builds from an SDC entry).
``Companion`` is the onboard computer (component MAV_COMP_ID_ONBOARD_COMPUTER) that carries the
gas sensors: its own HEARTBEAT (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID) and
NAMED_VALUE_FLOAT "CO2" (ppm) and "NOx" (ppb) at 2 Hz each. The autopilot's barometer and
thermometer go out as SCALED_PRESSURE (see ``MavSim``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fleet.catalog import DEFAULT_SDC
from fleet.geo import Position
from fleet.mavlink.wire import encode_text, mavlink
from fleet.simulation import SensorField, SensorSpec
from fleet.simulation.sensors import KIND_GPS, KIND_SCALAR

COMPONENT_ID = int(mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)
# NAMED_VALUE_FLOAT name -> the SDC quantity it carries.
NAMED_VALUES = {"CO2": "co2", "NOx": "nox"}
_HEARTBEAT_S = 1.0
_VALUES_S = 0.5


def sdc_sensor(quantity: str) -> SensorSpec:
    """The default catalog's scalar sensor of a quantity (or its GPS for "gps"), as the
    platform builds its spec. Raises KeyError when the catalog has none."""
    for entry in DEFAULT_SDC:
        params = entry.get("params") or {}
        if (entry["kind"] == KIND_SCALAR and params.get("quantity") == quantity) or (
            quantity == KIND_GPS == entry["kind"]
        ):
            return SensorSpec(
                name=str(entry["name"]),
                kind=str(entry["kind"]),
                unit=str(entry.get("unit") or ""),
                params=dict(params),
            )
    raise KeyError(f"no scalar sensor of quantity {quantity!r} in the default catalog")


class FieldSensors:
    """Scalar readings of the seeded world ``SensorField(seed)``."""

    def __init__(self, seed: int) -> None:
        self.field = SensorField(seed)
        self._specs: dict[str, SensorSpec] = {}

    def value(self, quantity: str, position: Position, time_s: float) -> float:
        """The reading of the catalog's ``quantity`` sensor (its unit) at a place and time."""
        spec = self._specs.get(quantity)
        if spec is None:
            spec = self._specs[quantity] = sdc_sensor(quantity)
        return float(self.field.sample(spec, position, time_s)["value"])

    def gps(self, position: Position, time_s: float) -> dict[str, Any]:
        """The catalog's GPS fix near a true position: lat, lng, alt, satellites, hdop."""
        spec = self._specs.get(KIND_GPS)
        if spec is None:
            spec = self._specs[KIND_GPS] = sdc_sensor(KIND_GPS)
        return self.field.sample(spec, position, time_s)


class Companion:
    """The onboard computer. ``send`` sends from its component id (it gets pymavlink's MAVLink
    object), ``where`` says where the vehicle is and the simulated time, ``wall`` is the
    wall clock (seconds since boot)."""

    def __init__(
        self,
        sensors: FieldSensors,
        send: Callable[[Callable[[Any], None]], None],
        where: Callable[[], tuple[Position, float]],
        wall: Callable[[], float],
    ) -> None:
        self._sensors = sensors
        self._send = send
        self._where = where
        self._wall = wall
        self._next_heartbeat = 0.0
        self._next_values = 0.0

    def tick(self) -> None:
        wall = self._wall()
        if wall >= self._next_heartbeat:
            self._next_heartbeat = max(self._next_heartbeat + _HEARTBEAT_S, wall)
            self._send(
                lambda mav: mav.heartbeat_send(
                    mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                    mavlink.MAV_AUTOPILOT_INVALID,
                    0,
                    0,
                    mavlink.MAV_STATE_ACTIVE,
                )
            )
        if wall >= self._next_values:
            self._next_values = max(self._next_values + _VALUES_S, wall)
            position, time_s = self._where()
            boot_ms = int(wall * 1000) & 0xFFFFFFFF
            for name, quantity in NAMED_VALUES.items():
                value = self._sensors.value(quantity, position, time_s)
                self._send_value(boot_ms, name, value)

    def _send_value(self, boot_ms: int, name: str, value: float) -> None:
        self._send(lambda mav: mav.named_value_float_send(boot_ms, encode_text(name, 10), value))
