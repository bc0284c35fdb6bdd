"""The pure cores import no Django (STYLE.md: tested in milliseconds without a database).

The import contract "pure-cores" in pyproject.toml checks the same statically, import by
import; this test checks what actually gets loaded when they are imported."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PURE = [
    "fleet.geo",
    "fleet.kinematics",
    "fleet.airspace",
    "fleet.service_area",
    "fleet.driving",
    "fleet.sources",
    "fleet.simulation",
    "vvm_worker.runtime",
    "vvm_worker.planning",
    "vvm_worker.scenario",
    "vvm_worker.mapping",
    "vvm_worker.scenario_gen",
    "vvm_worker.dispatch",
    "vvm_worker.delivery",
    "vvm_worker.clock",
    "vvm_worker.control",
    "vvm_worker.imaging",
    "fleet.catalog",
    "fleet.mavlink",
    "missions.readings",
    "cpcc_client.cli",  # the customers' command line runs without Django
]


def test_pure_cores_do_not_import_django() -> None:
    code = (
        "import importlib, sys\n"
        f"for name in {PURE!r}: importlib.import_module(name)\n"
        "loaded = sorted(m for m in sys.modules if m == 'django' or m.startswith('django.'))\n"
        "print(','.join(loaded))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == ""
