"""Managing customers (tenants) and their quotas through the REST API."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypedDict

from django.core.exceptions import ValidationError
from django.db import transaction
from django.utils.text import slugify

from accounts.models import Customer
from fleet.models import SensorType
from fleet.selectors import UnknownSensors, sensors_by_name
from missions.models import ENDED_STATUSES
from vvm_worker.services import VVM

# The VVM-API calls a customer's VVs may be limited to (the names vvm_worker/runtime/prelude.js
# checks with allowed(...)).
VVM_API_CALLS = (
    "log",
    "sensor.get",
    "sensor.list",
    "storage.list",
    "storage.load",
    "storage.remove",
    "storage.store",
    "task.execute",
    "task.executeAll",
)


class CustomerConfig(TypedDict, total=False):
    """What an administrator sets on a customer (model field names)."""

    name: str
    slug: str
    privileged: bool
    max_parallel_vvs: int
    max_tasks_per_vv: int
    storage_bytes: int
    cpu_ms_per_step: int
    heap_bytes: int
    allowed_api_calls: list[str]


class CustomerBusy(RuntimeError):
    """The customer has VVs that have not ended, so it cannot be deleted."""

    def __init__(self, customer: Customer, count: int) -> None:
        super().__init__(f"{customer.name} has {count} VV(s) that have not ended")
        self.customer = customer
        self.count = count


def _sensor_entries(names: Sequence[str]) -> list[SensorType]:
    try:
        return sensors_by_name(names=names)
    except UnknownSensors as exc:
        raise ValidationError({"allowed_sensors": str(exc)}) from None


def _validate(customer: Customer) -> None:
    unknown = sorted(set(customer.allowed_api_calls or ()) - set(VVM_API_CALLS))
    if unknown:
        raise ValidationError(
            {
                "allowed_api_calls": "unknown VVM-API calls: "
                + ", ".join(repr(c) for c in unknown)
                + "; known: "
                + ", ".join(VVM_API_CALLS)
            }
        )
    if not customer.slug:
        customer.slug = slugify(customer.name)
    customer.full_clean()


def customer_create(
    *, config: CustomerConfig, allowed_sensors: Sequence[str] | None = None
) -> Customer:
    """Add a customer with its quotas (defaults for those not given); ``allowed_sensors``
    empty or None means every unprivileged SDC entry (privileged ones too for a privileged
    customer). Raises ValidationError naming the field."""
    entries = _sensor_entries(allowed_sensors or [])
    with transaction.atomic():
        customer = Customer(**config)
        _validate(customer)
        customer.save()
        customer.allowed_sensors.set(entries)
    return customer


def customer_update(
    *,
    customer: Customer,
    config: CustomerConfig,
    allowed_sensors: Sequence[str] | None,
    vvm: VVM,
) -> Customer:
    """Change a customer's name or quotas; ``allowed_sensors`` None keeps them.

    New quotas hold for the next step of each VV; more parallel VVs admit queued ones at once.
    VVs keep the SDC entries they were submitted with. Raises ValidationError naming the field.
    """
    entries = None if allowed_sensors is None else _sensor_entries(allowed_sensors)
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=customer.pk)
        before = customer.max_parallel_vvs
        for name, value in config.items():
            setattr(customer, name, value)
        _validate(customer)
        customer.save()
        if entries is not None:
            customer.allowed_sensors.set(entries)
        if customer.max_parallel_vvs > before:
            vvm.dispatcher.customer_slot_freed(customer.pk)
    return customer


def customer_delete(*, customer: Customer) -> None:
    """Delete a customer with its users and its VVs' data; CustomerBusy while any of its VVs
    has not ended (cancel them first)."""
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=customer.pk)
        busy = customer.vvs.exclude(status__in=ENDED_STATUSES).count()
        if busy:
            raise CustomerBusy(customer, busy)
        customer.delete()
