"""The VVM as the web application and the workers use it: wall-clock time, and work handed to the hosts'
workers through Celery once a request's transaction commits."""

from __future__ import annotations

from django.conf import settings

from fleet.simulation import PLATFORM_WORLD_SEED, SensorField
from vvm_worker.celery_dispatch import CeleryDispatcher, CeleryNotifier
from vvm_worker.clock import SystemClock
from vvm_worker.dispatch import LocalHost
from vvm_worker.live import FeedAnnouncer
from vvm_worker.services import VVM


def platform_vvm(*, local: LocalHost | None = None) -> VVM:
    """A VVM for a request of the web application, an admin action or a host's worker
    (``local``: the RVs or the ground station whose own work skips the broker, whose host
    publishes the changes of each piece of its work at once, from a thread of their own).
    Each has a runtime of its own."""
    return VVM(
        clock=SystemClock(),
        dispatcher=CeleryDispatcher(local=local),
        field=SensorField(PLATFORM_WORLD_SEED),
        lease_s=settings.CPCC_RV_LEASE_S,
        announcer=FeedAnnouncer(batched=local is not None, in_background=local is not None),
        notifier=CeleryNotifier(),
    )
