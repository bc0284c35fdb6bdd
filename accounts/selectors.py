"""What a customer may do (its quotas as runtime limits, the SDC entries it may use), and the
customers as staff see them."""

from __future__ import annotations

from typing import Any

from django.db.models import Count, Q, QuerySet

from accounts.models import Customer
from fleet.models import SensorType
from missions.models import ENDED_STATUSES
from vvm_worker.runtime.types import Limits


def customer_limits(*, customer: Customer) -> Limits:
    calls = customer.allowed_api_calls or None
    return Limits(
        cpu_s=customer.cpu_ms_per_step / 1000.0,
        heap_bytes=customer.heap_bytes,
        storage_bytes=customer.storage_bytes,
        max_tasks=customer.max_tasks_per_vv,
        allowed_calls=frozenset(calls) if calls else None,
    )


def customer_catalog(*, customer: Customer) -> list[dict[str, Any]]:
    """The SDC entries the customer's VVs may use, as the VVM-API shows them."""
    entries = SensorType.objects.all()
    chosen = customer.allowed_sensors.all() if customer.pk else SensorType.objects.none()
    if chosen.exists():
        entries = chosen
    if not customer.privileged:
        entries = entries.filter(privileged=False)
    return [e.as_catalog_entry() for e in entries.order_by("name")]


def customer_list() -> QuerySet[Customer]:
    """Every customer (staff data) with its allowed SDC entries, its users, and how many of
    its VVs have not ended."""
    return (
        Customer.objects.prefetch_related("allowed_sensors", "users")
        .annotate(vvs_active=Count("vvs", filter=~Q(vvs__status__in=ENDED_STATUSES)))
        .order_by("name")
    )
