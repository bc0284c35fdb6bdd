"""Where each sensor of an RV gets its readings: its sensor sources (issue 24).

A vehicle's ``sensor_sources`` maps the names of the SDC entries it carries to where their
values come from; a sensor it carries without an entry there reads the field (as every RV
did before sources existed):

- ``field``: the platform's simulated sensor world;
- ``telemetry``: what the autopilot publishes, the way ArduPilot and PX4 do: GPS and altitude
  from ``GLOBAL_POSITION_INT`` (with ``GPS_RAW_INT``'s satellites and HDOP), barometer and
  temperature from ``SCALED_PRESSURE``, battery from ``SYS_STATUS``;
- ``named_value``: a gas sensor on a companion component, as ``NAMED_VALUE_FLOAT`` (``name``:
  the value's name, at most 10 characters; by default the SDC entry's name);
- ``camera``: the MAVLink camera protocol (``MAV_CMD_IMAGE_START_CAPTURE`` to the camera
  component, its ``CAMERA_IMAGE_CAPTURED``, and the picture fetched from the URI it gives);
- ``plugin``: a sensor attached to the vehicle's own computer, read by a plug-in
  (``plugin``: its name in the ``cpcc.sensors`` entry point group; ``options``: what its class
  takes, e.g. the serial port).

Every source but ``field`` takes ``timeout_s`` (default 2 s): a reading that does not come
within it fails the task. Pure Python: the admin, the vehicle API and the workers check a
configuration with ``parse_sources`` against the SDC entries' kinds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fleet.plugins import PluginError, plugin_class

FIELD, TELEMETRY, NAMED_VALUE, CAMERA, PLUGIN = (
    "field",
    "telemetry",
    "named_value",
    "camera",
    "plugin",
)
SOURCES = (FIELD, TELEMETRY, NAMED_VALUE, CAMERA, PLUGIN)
# What only a vehicle that speaks MAVLink has.
MAVLINK_SOURCES = frozenset({TELEMETRY, NAMED_VALUE, CAMERA})
# The scalar quantities the autopilot's telemetry carries (SDC params "quantity").
TELEMETRY_QUANTITIES = ("altitude", "pressure", "temperature", "battery")
NAMED_VALUE_MAX = 10  # NAMED_VALUE_FLOAT.name is char[10]
DEFAULT_TIMEOUT_S = 2.0
MAX_TIMEOUT_S = 60.0
# The keys each source takes, besides "source".
_KEYS: Mapping[str, frozenset[str]] = {
    FIELD: frozenset(),
    TELEMETRY: frozenset({"timeout_s"}),
    NAMED_VALUE: frozenset({"name", "timeout_s"}),
    CAMERA: frozenset({"timeout_s"}),
    PLUGIN: frozenset({"plugin", "options", "timeout_s"}),
}


class SourceError(ValueError):
    """A sensor-source configuration that cannot work; the message says where and why."""


@dataclass(frozen=True)
class SensorSource:
    """Where one sensor's readings come from (see the module docstring)."""

    source: str
    name: str = ""
    plugin: str = ""
    options: Mapping[str, Any] = field(default_factory=dict)
    timeout_s: float = DEFAULT_TIMEOUT_S

    def as_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {"source": self.source}
        if self.name:
            data["name"] = self.name
        if self.plugin:
            data["plugin"] = self.plugin
            data["options"] = dict(self.options)
        if self.source != FIELD and self.timeout_s != DEFAULT_TIMEOUT_S:
            data["timeout_s"] = self.timeout_s
        return data


DEFAULT = SensorSource(FIELD)  # of a sensor the vehicle's configuration does not name


def autopilot_source(entry: Mapping[str, Any]) -> SensorSource:
    """Where an ArduPilot or PX4 vehicle with a companion computer and a MAVLink camera
    publishes an SDC entry's readings (and ``manage.py mavsim`` does): the telemetry for GPS,
    altitude, pressure, temperature and battery, the camera protocol for a camera, a named
    value of the entry's name for any other scalar (a gas sensor)."""
    kind = entry.get("kind")
    if kind == "camera":
        return SensorSource(CAMERA)
    if kind == "gps" or _quantity(entry) in TELEMETRY_QUANTITIES:
        return SensorSource(TELEMETRY)
    return SensorSource(NAMED_VALUE, name=str(entry.get("name", ""))[:NAMED_VALUE_MAX])


def source_for(sources: Mapping[str, SensorSource], name: str) -> SensorSource:
    """The source of the SDC entry of this name on a vehicle with these ``sources``."""
    return sources.get(name, DEFAULT)


def parse_sources(
    data: Any, *, catalog: Mapping[str, Mapping[str, Any]], mavlink: bool
) -> dict[str, SensorSource]:
    """A vehicle's ``sensor_sources`` as stored (JSON), checked: each key an SDC entry of
    ``catalog`` (name -> ``{kind, params}``), each value a source that suits the entry's kind
    and the vehicle (``mavlink``: it speaks MAVLink). Raises SourceError naming the sensor."""
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise SourceError(
            "sensor sources must be an object mapping SDC entry names to sources, "
            f"not {type(data).__name__}"
        )
    parsed = {}
    for name, config in data.items():
        entry = catalog.get(name)
        if entry is None:
            known = ", ".join(sorted(catalog)) or "none"
            raise SourceError(f"sensor {name!r}: no SDC entry of that name (entries: {known})")
        try:
            parsed[name] = _parse_one(config, entry, mavlink=mavlink)
        except SourceError as exc:
            raise SourceError(f"sensor {name!r}: {exc}") from None
    return parsed


def _parse_one(config: Any, entry: Mapping[str, Any], *, mavlink: bool) -> SensorSource:
    if not isinstance(config, Mapping):
        raise SourceError(f'expected an object such as {{"source": "field"}}, got {config!r}')
    source = config.get("source")
    if source not in SOURCES:
        raise SourceError(f"unknown source {source!r} (sources: {', '.join(SOURCES)})")
    extra = sorted(set(config) - {"source"} - _KEYS[source])
    if extra:
        allowed = ", ".join(sorted(_KEYS[source])) or "nothing else"
        raise SourceError(f"{source} takes no {', '.join(extra)} (it takes {allowed})")
    if source in MAVLINK_SOURCES and not mavlink:
        raise SourceError(f"{source} needs a vehicle that speaks MAVLink (its driver: mavlink)")
    kind, quantity = entry.get("kind"), _quantity(entry)
    timeout_s = _timeout(config.get("timeout_s", DEFAULT_TIMEOUT_S))
    if source == FIELD:
        return SensorSource(FIELD)
    if source == TELEMETRY:
        if kind != "gps" and quantity not in TELEMETRY_QUANTITIES:
            raise SourceError(
                f"the autopilot's telemetry has no {quantity or kind} (it has GPS, "
                f"{', '.join(TELEMETRY_QUANTITIES)})"
            )
        return SensorSource(TELEMETRY, timeout_s=timeout_s)
    if source == NAMED_VALUE:
        if kind != "scalar":
            raise SourceError(f"a named value is a number: not for a {kind} sensor")
        name = config.get("name", str(entry.get("name", ""))[:NAMED_VALUE_MAX])
        if not isinstance(name, str) or not name or len(name) > NAMED_VALUE_MAX:
            raise SourceError(
                f"name must be the NAMED_VALUE_FLOAT name, 1 to {NAMED_VALUE_MAX} characters, "
                f"not {name!r}"
            )
        if not name.isascii() or not name.isprintable():
            raise SourceError(f"name must be printable ASCII, not {name!r}")
        return SensorSource(NAMED_VALUE, name=name, timeout_s=timeout_s)
    if source == CAMERA:
        if kind != "camera":
            raise SourceError(f"the MAVLink camera takes pictures: not for a {kind} sensor")
        return SensorSource(CAMERA, timeout_s=timeout_s)
    plugin, options = config.get("plugin"), config.get("options", {})
    if not isinstance(plugin, str) or not plugin:
        raise SourceError("plugin must name a plug-in of the cpcc.sensors entry point group")
    if not isinstance(options, Mapping):
        raise SourceError(f"options must be an object, not {options!r}")
    try:
        cls = plugin_class(plugin)
        cls.check_options(dict(options))
    except PluginError as exc:
        raise SourceError(str(exc)) from None
    if cls.kind != kind:
        raise SourceError(f"plug-in {plugin!r} reads {cls.kind} sensors, not {kind} ones")
    return SensorSource(PLUGIN, plugin=plugin, options=dict(options), timeout_s=timeout_s)


def _quantity(entry: Mapping[str, Any]) -> str:
    params = entry.get("params") or {}
    return str(params.get("quantity", "")).lower() if isinstance(params, Mapping) else ""


def _timeout(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SourceError(f"timeout_s must be a number of seconds, not {value!r}")
    if not 0 < value <= MAX_TIMEOUT_S:
        raise SourceError(
            f"timeout_s must be more than 0 and at most {MAX_TIMEOUT_S:g}, not {value}"
        )
    return float(value)
