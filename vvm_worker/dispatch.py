"""How the VVM hands work to the host that must do it next.

The services change state in the database and then tell a `Dispatcher` who must act: the
host a VV moved to, a vehicle whose open tasks changed, a customer with a free slot. In
`simulate` the dispatcher puts events on the discrete-event queue; in the distributed
platform it sends Celery tasks to the host's queue once the transaction commits.
"""

from __future__ import annotations

import uuid
from typing import Protocol


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


class NullDispatcher:
    """Records nothing and wakes nobody: for loading data with no hosts running yet."""

    def vv_arrived(self, vv_id: uuid.UUID) -> None:
        pass

    def vehicle_changed(self, vehicle_id: int) -> None:
        pass

    def customer_slot_freed(self, customer_id: int) -> None:
        pass
