"""The SDC entries a customer (or a user) may use, and the customers as staff see them."""

from __future__ import annotations

from typing import Any

from django.db.models import QuerySet

from accounts.models import Customer, User
from fleet.models import SensorType


def customer_catalog(*, customer: Customer) -> list[dict[str, Any]]:
    """The SDC entries the customer's VVs may use, as the VVM-API shows them."""
    entries = SensorType.objects.all()
    chosen = customer.allowed_sensors.all() if customer.pk else SensorType.objects.none()
    if chosen.exists():
        entries = chosen
    if not customer.privileged:
        entries = entries.filter(privileged=False)
    return [e.as_catalog_entry() for e in entries.order_by("name")]


def sensor_list_for_user(*, user: User) -> QuerySet[SensorType]:
    """The SDC entries a user may use: all of them for staff, the customer's catalog (its
    allowed entries, privileged ones only for privileged customers) for a customer's user,
    none for anyone else."""
    entries = SensorType.objects.order_by("name")
    if user.is_staff:
        return entries
    if user.customer is None:
        return entries.none()
    names = [e["name"] for e in customer_catalog(customer=user.customer)]
    return entries.filter(name__in=names)


def customer_list() -> QuerySet[Customer]:
    """Every customer (staff data) with its allowed SDC entries and its users."""
    return Customer.objects.prefetch_related("allowed_sensors", "users").order_by("name")
