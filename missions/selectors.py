"""Reading VVs and their data, always scoped to the customer who asks."""

from __future__ import annotations

import uuid

from django.db.models import QuerySet

from accounts.models import User
from missions.models import VirtualVehicle


class VVNotFound(LookupError):
    """No such VV for this user: it does not exist or belongs to another customer."""


def vv_list_for_user(*, user: User) -> QuerySet[VirtualVehicle]:
    """The VVs a user may see: staff see every VV, a customer's user their customer's."""
    qs = VirtualVehicle.objects.select_related("customer", "host_gs", "host_rv")
    if user.is_staff:
        return qs
    if user.customer_id is None:
        return qs.none()
    return qs.filter(customer_id=user.customer_id)


def vv_get_for_user(*, user: User, vv_id: uuid.UUID | str) -> VirtualVehicle:
    """One VV the user may see; VVNotFound both for a missing VV and another customer's."""
    try:
        return vv_list_for_user(user=user).get(pk=vv_id)
    except (VirtualVehicle.DoesNotExist, ValueError):
        raise VVNotFound(str(vv_id)) from None
