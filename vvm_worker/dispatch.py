"""How the VVM hands work to the host that must do it next.

The services change state in the database and then tell a `Dispatcher` who must act: the
host a VV moved to, a vehicle whose open tasks changed, a customer with a free slot. In
`simulate` the dispatcher puts events on the discrete-event queue; in the distributed
platform `vvm_worker.celery_dispatch.CeleryDispatcher` sends Celery tasks to the host's queue
once the transaction commits. This module is the interface and the addresses only (queue and
task names), so the services, the Celery tasks and the dispatcher never import each other.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from typing import Any, Protocol


@dataclass(frozen=True)
class HostRef:
    """A host by kind and id: an RV (``rv_id``) or a ground station (``gs_id``)."""

    rv_id: int | None = None
    gs_id: int | None = None


class Dispatcher(Protocol):
    def vv_arrived(self, vv_id: uuid.UUID, *, on: HostRef | None = None) -> None:
        """The VV is on a new host (or must be looked at again by its host): advance it.
        ``on``: the host the caller's transaction put it on, when the caller knows it (the
        dispatcher need not look it up)."""
        ...

    def vv_wake_later(self, vv_id: uuid.UUID, delay_s: float) -> None:
        """Advance the VV on its host ``delay_s`` seconds from now (platform clock): a VV that
        waits for a message until then looks again (a message wakes it sooner by
        ``vv_arrived``)."""
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

# The Celery tasks (vvm_worker/tasks.py) by name: the dispatcher sends them without importing
# the module that runs them.
VV_ADVANCE_TASK = "cpcc.vv_advance"
VEHICLE_CHANGED_TASK = "cpcc.vehicle_changed"
ADMIT_TASK = "cpcc.admit"


class LocalHost(Protocol):
    """The RVs (an RV worker hosts one or several) or the ground station this process runs,
    for work it can do itself without a message."""

    def is_vehicle(self, vehicle_id: int) -> bool:
        """Whether this process hosts the vehicle."""
        ...

    def is_station(self, station_id: int) -> bool:
        """Whether this process hosts the ground station."""
        ...

    def advance_later(self, vv_id: uuid.UUID) -> None:
        """Advance the VV, which is on one of this process's hosts, on its host thread."""
        ...

    def wake_later(self, vehicle_id: int) -> None:
        """The open tasks or status of this vehicle (one of this process's) changed: its
        control loop re-plans on the host thread."""
        ...


class Announcer(Protocol):
    """Who hears of changes as they happen (the live map): the services announce a change with
    what it is; an announcer in the distributed platform publishes it once the transaction
    commits, so a rolled-back change is never announced."""

    def announce(self, event: dict[str, Any]) -> None: ...

    def flush(self) -> None:
        """Publish what waits (an announcer that batches the changes of a host's work)."""

    def close(self) -> None:
        """Publish what waits and stop (the end of a host's work)."""


class Silent:
    """The announcer of `simulate` and of tests: nobody listens."""

    def announce(self, event: dict[str, Any]) -> None:
        pass

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass
