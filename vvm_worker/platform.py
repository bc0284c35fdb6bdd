"""The VVM as the web application and the workers use it: wall-clock time, and work handed
to the hosts' workers through Celery."""

from __future__ import annotations

from fleet.simulation import SensorField
from vvm_worker.clock import SystemClock
from vvm_worker.dispatch import NullDispatcher
from vvm_worker.services import VVM


def platform_vvm() -> VVM:
    """A VVM for a request of the web application."""
    return VVM(clock=SystemClock(), dispatcher=NullDispatcher(), field=SensorField(0))
