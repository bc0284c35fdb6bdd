"""The VVM as the web application uses it: wall-clock time, and work handed to the hosts'
workers through Celery once a request's transaction commits."""

from __future__ import annotations

from django.conf import settings

from fleet.simulation import SensorField
from vvm_worker.clock import SystemClock
from vvm_worker.dispatch import CeleryDispatcher
from vvm_worker.services import VVM


def platform_vvm() -> VVM:
    """A VVM for a request of the web application or an admin action."""
    return VVM(
        clock=SystemClock(),
        dispatcher=CeleryDispatcher(),
        field=SensorField(0),
        lease_s=settings.CPCC_RV_LEASE_S,
    )
