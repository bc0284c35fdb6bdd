"""The SDC entries a customer (or a user) may use, and the customers as staff see them."""

from __future__ import annotations

from typing import Any

from django.db.models import Exists, OuterRef, QuerySet

from accounts.models import Customer, User
from fleet.models import SensorType


def customer_catalog(*, customer: Customer) -> list[dict[str, Any]]:
    """The SDC entries the customer's VVs may use, as the VVM-API shows them."""
    # One read: every entry, each saying whether the customer's list holds it.
    through = Customer.allowed_sensors.through
    mine = through.objects.filter(customer_id=customer.pk, sensortype_id=OuterRef("pk"))
    every = list(SensorType.objects.annotate(chosen=Exists(mine)).order_by("name"))
    chosen = [e for e in every if e.chosen]
    entries = chosen if customer.pk and chosen else every
    if not customer.privileged:
        entries = [e for e in entries if not e.privileged]
    return [e.as_catalog_entry() for e in entries]


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
