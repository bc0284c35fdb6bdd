"""Sensors attached to a vehicle's own computer: the plug-in interface (issue 24).

A plug-in is a class registered in the ``cpcc.sensors`` entry point group (a package's
``pyproject.toml``: ``[project.entry-points."cpcc.sensors"] my-sensor = "pkg.mod:MySensor"``),
one class per sensor kind. A vehicle's sensor source names it with the options its class takes
(``fleet.sources``); the RV worker makes one instance per sensor when it starts and asks it for
a reading at each stop. The platform ships ``mhz19`` (``fleet.plugins.mhz19``), a CO2 sensor
on a serial line.

A class subclasses ``SensorPlugin``: ``kind`` (``scalar`` for a number), ``check_options``
(raises PluginError saying which option is wrong and why), ``read`` (the kind-specific fields
of one reading, e.g. ``{"value": 415.0}``, or SensorFailure saying why there is none) and
``close``.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any, ClassVar

GROUP = "cpcc.sensors"


class PluginError(ValueError):
    """A plug-in that cannot be loaded or options it refuses; the message says which and why."""


class SensorPlugin:
    """The base of a sensor plug-in (see the module docstring)."""

    kind: ClassVar[str] = "scalar"

    @classmethod
    def check_options(cls, options: dict[str, Any]) -> None:
        """Raise PluginError if the options cannot work (without touching the device)."""

    def __init__(self, **options: Any) -> None:
        self.check_options(options)
        self.options = options

    def read(self, timeout_s: float) -> dict[str, Any]:
        """One reading's kind-specific fields, within ``timeout_s``; SensorFailure if none."""
        raise NotImplementedError

    def close(self) -> None:
        """Let go of the device."""


def plugin_names() -> list[str]:
    return sorted(ep.name for ep in entry_points(group=GROUP))


def plugin_class(name: str) -> type[SensorPlugin]:
    """The class registered under this name; PluginError naming the plug-ins there are."""
    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        known = ", ".join(plugin_names()) or "none"
        raise PluginError(f"no sensor plug-in named {name!r} (plug-ins: {known})")
    try:
        cls = found[0].load()
    except Exception as exc:  # a broken third-party package: say which and why
        raise PluginError(f"sensor plug-in {name!r} cannot be loaded: {exc}") from exc
    if not (isinstance(cls, type) and issubclass(cls, SensorPlugin)):
        raise PluginError(f"sensor plug-in {name!r} is not a SensorPlugin class")
    return cls
