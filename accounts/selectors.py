"""The SDC entries a customer (or a user) may use, the customers as staff see them, and a user's
own API tokens and webhooks."""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ObjectDoesNotExist
from django.db.models import Exists, OuterRef, QuerySet

from accounts.models import ApiToken, Customer, Invite, User, Webhook, WebhookDelivery
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


# --- API tokens and webhooks: each user's own tokens, each customer's own webhooks ---------------


class ApiTokenNotFound(LookupError):
    """No such token among the user's (another user's answers the same)."""


class WebhookNotFound(LookupError):
    """No such webhook among the user's customer's (another customer's answers the same)."""


def api_token_list_for_user(*, user: User) -> QuerySet[ApiToken]:
    """The user's named API tokens, newest first."""
    return ApiToken.objects.filter(user=user).order_by("-created", "-id")


def api_token_get_for_user(*, user: User, token_id: int) -> ApiToken:
    """One of the user's tokens; ApiTokenNotFound for a missing one and another user's."""
    try:
        return api_token_list_for_user(user=user).get(pk=token_id)
    except ApiToken.DoesNotExist:
        raise ApiTokenNotFound(token_id) from None


def legacy_token_for_user(*, user: User) -> Any | None:
    """The token an administrator made for the user with ``drf_create_token`` (DRF's, reached
    through the user: the selectors, which the services use, import nothing of DRF), if any."""
    try:
        return user.auth_token  # type: ignore[attr-defined]
    except ObjectDoesNotExist:
        return None


def webhook_list_for_user(*, user: User) -> QuerySet[Webhook]:
    """The webhooks of the user's customer, oldest first (none for a user of no customer)."""
    if user.customer_id is None:
        return Webhook.objects.none()
    return Webhook.objects.filter(customer_id=user.customer_id).order_by("created", "id")


def webhook_get_for_user(*, user: User, webhook_id: int) -> Webhook:
    """One of the user's customer's webhooks; WebhookNotFound for a missing one and for
    another customer's."""
    try:
        return webhook_list_for_user(user=user).get(pk=webhook_id)
    except Webhook.DoesNotExist:
        raise WebhookNotFound(webhook_id) from None


def webhook_deliveries_for_user(*, user: User, webhook_id: int) -> QuerySet[WebhookDelivery]:
    """The attempts to deliver to one of the user's customer's webhooks, newest first;
    WebhookNotFound as webhook_get_for_user."""
    webhook = webhook_get_for_user(user=user, webhook_id=webhook_id)
    return WebhookDelivery.objects.filter(webhook=webhook).order_by("-id")


# --- members and invitations: each customer's own --------------------------------------------


class MemberNotFound(LookupError):
    """No such member of the user's customer (another customer's answers the same)."""


class InviteNotFound(LookupError):
    """No such open invitation of the user's customer (another customer's answers the same)."""


def member_list_for_user(*, user: User) -> QuerySet[User]:
    """The active members of the user's customer, by user name (none for a user of no
    customer)."""
    if user.customer_id is None:
        return User.objects.none()
    return User.objects.filter(customer_id=user.customer_id, is_active=True).order_by("username")


def member_get_for_user(*, user: User, member_id: int) -> User:
    try:
        return member_list_for_user(user=user).get(pk=member_id)
    except User.DoesNotExist:
        raise MemberNotFound(member_id) from None


def invite_list_for_user(*, user: User) -> QuerySet[Invite]:
    """The invitations of the user's customer not accepted yet (expired ones too), newest
    first."""
    if user.customer_id is None:
        return Invite.objects.none()
    return Invite.objects.filter(customer_id=user.customer_id, accepted__isnull=True).order_by(
        "-created", "-id"
    )


def invite_get_for_user(*, user: User, invite_id: int) -> Invite:
    try:
        return invite_list_for_user(user=user).get(pk=invite_id)
    except Invite.DoesNotExist:
        raise InviteNotFound(invite_id) from None
