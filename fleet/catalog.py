"""The default system-wide device catalog (SDC), DESIGN.md section 2.

Plain data: the data migration that seeds the catalog and the tests read it.
"""

from __future__ import annotations

from typing import Any

CAMERA = {"width": 640, "height": 480, "format": "png"}

DEFAULT_SDC: tuple[dict[str, Any], ...] = (
    {"name": "Altimeter", "kind": "scalar", "unit": "m", "params": {"quantity": "altitude"}},
    {"name": "Barometer", "kind": "scalar", "unit": "hPa", "params": {"quantity": "pressure"}},
    {
        "name": "Battery",
        "kind": "scalar",
        "unit": "%",
        "params": {"quantity": "battery"},
        "privileged": True,
    },
    {"name": "CO2", "kind": "scalar", "unit": "ppm", "params": {"quantity": "co2"}},
    {"name": "GPS", "kind": "gps", "unit": "deg", "params": {}},
    {"name": "NOx", "kind": "scalar", "unit": "ppb", "params": {"quantity": "nox"}},
    {"name": "Thermometer", "kind": "scalar", "unit": "°C", "params": {"quantity": "temperature"}},
    {"name": "Camera 640x480", "kind": "camera", "unit": "", "params": {**CAMERA, "view": "front"}},
    {
        "name": "Belly Mounted Camera 640x480",
        "kind": "camera",
        "unit": "",
        "params": {**CAMERA, "view": "belly"},
    },
    {
        "name": "FPV Camera 640x480",
        "kind": "camera",
        "unit": "",
        "params": {**CAMERA, "view": "fpv"},
    },
)
