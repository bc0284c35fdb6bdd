"""Customers (tenants), their quotas and their users; the staff's own login."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypedDict

from django.contrib.auth.models import Group
from django.core.exceptions import ValidationError
from django.db import transaction
from django.utils.text import slugify

from accounts import roles
from accounts.models import Customer, ServiceClass, User
from missions.models import ENDED_STATUSES
from vvm_worker.runtime import VVM_API_CALLS, Limits
from vvm_worker.services.base import VVM, sensor_entries


class CustomerConfig(TypedDict, total=False):
    """What an administrator sets on a customer (model field names)."""

    name: str
    slug: str
    privileged: bool
    max_parallel_vvs: int
    max_queued_vvs: int
    max_tasks_per_vv: int
    storage_bytes: int
    cpu_ms_per_step: int
    heap_bytes: int
    max_messages_per_vv: int
    max_message_bytes: int
    allowed_api_calls: list[str]
    service_class: ServiceClass | None


class CustomerBusy(RuntimeError):
    """The customer has VVs that have not ended, so it cannot be deleted."""

    def __init__(self, customer: Customer, count: int) -> None:
        super().__init__(f"{customer.name} has {count} VV(s) that have not ended")
        self.customer = customer
        self.count = count


def customer_limits(*, customer: Customer) -> Limits:
    """The customer's quotas as the limits the runtime enforces on each step."""
    calls = customer.allowed_api_calls or None
    return Limits(
        cpu_s=customer.cpu_ms_per_step / 1000.0,
        heap_bytes=customer.heap_bytes,
        storage_bytes=customer.storage_bytes,
        max_tasks=customer.max_tasks_per_vv,
        allowed_calls=frozenset(calls) if calls else None,
        max_messages=customer.max_messages_per_vv,
        message_bytes=customer.max_message_bytes,
    )


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
    entries = sensor_entries(allowed_sensors or [], field="allowed_sensors")
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
    """Change a customer's name, quotas or service class; ``allowed_sensors`` None keeps them.

    New quotas hold for the next step of each VV; more parallel VVs admit queued ones at once,
    and so does a new class (unless it holds them: ``vvs._admit``).
    VVs keep the SDC entries they were submitted with. Raises ValidationError naming the field.
    """
    entries = (
        None
        if allowed_sensors is None
        else sensor_entries(allowed_sensors, field="allowed_sensors")
    )
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=customer.pk)
        before = customer.max_parallel_vvs, customer.service_class_id
        for name, value in config.items():
            setattr(customer, name, value)
        _validate(customer)
        customer.save()
        if entries is not None:
            customer.allowed_sensors.set(entries)
        # More parallel VVs start queued ones; a new class may hold them, or no longer.
        if customer.max_parallel_vvs > before[0] or customer.service_class_id != before[1]:
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


def service_class_save(*, name: str, p95_s: float, weight: float = 1.0) -> ServiceClass:
    """Create the service class ``name`` or change its target ``p95_s`` (seconds, > 0) and
    ``weight`` (> 0). A new target holds at the next admission of its customers' VVs.
    Raises ValidationError naming the field."""
    for field, value in (("p95_s", p95_s), ("weight", weight)):
        if not math.isfinite(value):
            raise ValidationError({field: f"must be a finite number, got {value!r}"})
    with transaction.atomic():
        service_class = ServiceClass.objects.select_for_update().filter(
            name=name
        ).first() or ServiceClass(name=name)
        service_class.p95_s, service_class.weight = p95_s, weight
        service_class.full_clean()
        service_class.save()
    return service_class


def customer_class_set(
    *, customer: Customer, service_class: ServiceClass | None, vvm: VVM
) -> Customer:
    """Put the customer in ``service_class`` (None: no class, so no target and weight 1).
    Its queued VVs are looked at again at once: the new class may hold them, or no longer.
    Raises ValidationError (naming ``service_class``) for a class that is not stored."""
    if service_class is not None and service_class.pk is None:
        raise ValidationError({"service_class": "save the service class first"})
    return customer_update(
        customer=customer, config={"service_class": service_class}, allowed_sensors=None, vvm=vvm
    )


def user_set_login(
    *,
    username: str,
    password: str,
    customer: Customer | None = None,
    staff: bool = False,
    role: str | None = None,
    groups: Sequence[str] | None = None,
) -> User:
    """Create the user (or take the existing one) and set its password.

    ``customer`` makes it one of that customer's users, with ``role`` (accounts.roles; None:
    a new user is an owner, an existing one keeps its role); ``staff`` an administrator of the
    platform (a superuser); ``groups`` staff in exactly these staff groups
    (accounts.roles.STAFF_GROUPS), with what they allow and no more.
    Raises ValueError for a role or a group that is not one, or a group the migrations have
    not made.
    """
    if role is not None and not roles.is_role(role):
        raise ValueError(f"{role!r} is not a role; one of {', '.join(roles.CUSTOMER_ROLES)}")
    unknown = sorted(set(groups or ()) - set(roles.STAFF_GROUPS))
    if unknown:
        raise ValueError(
            f"not staff groups: {', '.join(unknown)}; they are {', '.join(roles.STAFF_GROUPS)}"
        )
    with transaction.atomic():
        user, _ = User.objects.get_or_create(username=username)
        if customer is not None:
            user.customer = customer
        if role is not None:
            user.role = role
        if staff:
            user.is_staff = user.is_superuser = True
        if groups is not None:
            user.is_staff = True
        user.set_password(password)
        user.save()
        if groups is not None:
            found = list(Group.objects.filter(name__in=groups))
            if len(found) != len(set(groups)):
                raise ValueError("the staff groups are missing: run manage.py migrate")
            user.groups.set(found)
    return user
