"""Celery tasks: the messages between hosts. They carry ids only; the database holds the state.

Every task is safe to run twice (``acks_late``: Celery delivers at least once) and returns only
after its work is committed, so a worker that dies mid-task leaves the message to be delivered
again, and a worker that restarts recovers from the database anyway. A database outage is
waited out and the work done again, the message unacknowledged meanwhile.
"""

from __future__ import annotations

import uuid

from celery import shared_task

from cpcc_site import database
from vvm_worker.dispatch import ADMIT_TASK, VEHICLE_CHANGED_TASK, VV_ADVANCE_TASK
from vvm_worker.hosts import GSHost, current_host
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_admit_queued
from vvm_worker.services import vv_advance as advance


@shared_task(name=VV_ADVANCE_TASK, acks_late=True, ignore_result=True)
def vv_advance(vv_id: str) -> None:
    """The VV arrived on one of this worker's hosts (or must be looked at again): step and
    route it (an RV worker does it on its host thread, whichever of its vehicles it is on)."""
    host = current_host()
    if host is None:
        database.through_outages(lambda: advance(vv_id=uuid.UUID(vv_id), vvm=platform_vvm()))
    else:
        database.through_outages(lambda: host.advance(uuid.UUID(vv_id)))


@shared_task(name=VEHICLE_CHANGED_TASK, acks_late=True, ignore_result=True)
def vehicle_changed(vehicle_id: int) -> None:
    """A vehicle of this worker has new work or a new status: its control loop re-plans."""
    host = current_host()
    if host is not None:
        host.wake(vehicle_id)


@shared_task(name=ADMIT_TASK, acks_late=True, ignore_result=True)
def admit(customer_id: int) -> None:
    """Start the customer's queued VVs as far as its quota allows (any ground station)."""
    host = current_host()
    if isinstance(host, GSHost):
        database.through_outages(lambda: host.admit(customer_id))
    else:
        database.through_outages(
            lambda: vv_admit_queued(customer_id=customer_id, vvm=platform_vvm())
        )
