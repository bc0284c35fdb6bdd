"""How the VVM hands work to the host that must do it next.

The services change state in the database and then tell a `Dispatcher` who must act: the
host a VV moved to, a vehicle whose open tasks changed, a customer with a free slot. In
`simulate` the dispatcher puts events on the discrete-event queue; in the distributed
platform it sends Celery tasks to the host's queue once the transaction commits.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable
from typing import Any, Protocol

from django.db import transaction

logger = logging.getLogger("cpcc.dispatch")


class Dispatcher(Protocol):
    def vv_arrived(self, vv_id: uuid.UUID) -> None:
        """The VV is on a new host (or must be looked at again by its host): advance it."""
        ...

    def vehicle_changed(self, vehicle_id: int) -> None:
        """The vehicle's open tasks or status changed: its control loop must re-plan."""
        ...

    def customer_slot_freed(self, customer_id: int) -> None:
        """A VV of the customer ended: admit queued ones."""
        ...


def gs_queue(gs_id: int) -> str:
    return f"gs.{gs_id}"


def rv_queue(vehicle_id: int) -> str:
    return f"rv.{vehicle_id}"


# Admission and other work any ground-station worker may do.
SHARED_QUEUE = "vvm"


class CeleryDispatcher:
    """Hands work to the hosts' Celery workers, once the transaction that made it commits.

    A VV goes to the queue of the host it is on at that moment, a vehicle's wake-up to the
    vehicle's queue. ``local`` lets a host do its own work in its own thread without a round
    trip through Redis (an RV resuming a VV it keeps, or re-planning after new work).
    """

    def __init__(self, local: LocalHost | None = None) -> None:
        self.local = local

    def vv_arrived(self, vv_id: uuid.UUID) -> None:
        transaction.on_commit(lambda: _safely(self._send_vv, vv_id))

    def vehicle_changed(self, vehicle_id: int) -> None:
        transaction.on_commit(lambda: _safely(self._send_vehicle, vehicle_id))

    def customer_slot_freed(self, customer_id: int) -> None:
        transaction.on_commit(lambda: _safely(_send_admit, customer_id))

    def _send_vv(self, vv_id: uuid.UUID) -> None:
        from missions.models import VirtualVehicle
        from vvm_worker.tasks import vv_advance

        host = (
            VirtualVehicle.objects.filter(pk=vv_id).values_list("host_gs_id", "host_rv_id").first()
        )
        if host is None:
            return
        gs_id, rv_id = host
        if rv_id is not None and self.local is not None and self.local.is_vehicle(rv_id):
            self.local.advance_later(vv_id)
            return
        queue = rv_queue(rv_id) if rv_id is not None else gs_queue(gs_id) if gs_id else SHARED_QUEUE
        vv_advance.apply_async(args=[str(vv_id)], queue=queue)

    def _send_vehicle(self, vehicle_id: int) -> None:
        from vvm_worker.tasks import vehicle_changed

        if self.local is not None and self.local.is_vehicle(vehicle_id):
            self.local.wake_later()
            return
        vehicle_changed.apply_async(args=[vehicle_id], queue=rv_queue(vehicle_id))


class LocalHost(Protocol):
    """The RV this process runs, for work it can do itself."""

    def is_vehicle(self, vehicle_id: int) -> bool: ...
    def advance_later(self, vv_id: uuid.UUID) -> None: ...
    def wake_later(self) -> None: ...


def _send_admit(customer_id: int) -> None:
    from vvm_worker.tasks import admit

    admit.apply_async(args=[customer_id], queue=SHARED_QUEUE)


def _safely(send: Callable[[Any], None], arg: Any) -> None:
    """Send a message; if the broker is unreachable, say so and go on: the state is committed,
    and the hosts' periodic sweeps find the work (a message is only a hint)."""
    try:
        send(arg)
    except Exception:
        logger.exception("could not hand work to a worker; the hosts' sweeps will find it")
