"""The accounts' services: every state change of a user's or a customer's own, one
keyword-only function each: API tokens (made and revoked on the Account page and at
``/api/v1/tokens/``), webhooks and the e-mails a user chooses (which keep
``Customer.notify_events``, what ``vvm_worker.services.notifications`` reads to know whether
anyone listens).

A token is django-rest-knox's (accounts.ApiToken): the key is shown once, when it is made; only
its digest and its first characters are kept. Revoking one deletes it, which forgets it at once
in this process's token cache (accounts/signals.py) and within ``CPCC_TOKEN_CACHE_S`` in the
others. The single token per user that ``manage.py drf_create_token`` makes (DRF's) keeps
working beside them, and its owner may revoke it too.
"""

from __future__ import annotations

import datetime as dt
import logging
import secrets
from collections.abc import Callable, Sequence

from django.conf import settings
from django.contrib.auth.password_validation import validate_password
from django.core import signing
from django.core.exceptions import ValidationError
from django.core.mail import send_mail
from django.core.validators import EmailValidator
from django.db import IntegrityError, transaction
from django.utils import timezone

from accounts import roles
from accounts.models import ApiToken, Customer, Invite, NotifyEvent, User, Webhook
from accounts.selectors import legacy_token_for_user
from cpcc_site.names import plain_name_problem
from vvm_worker import delivery

logger = logging.getLogger("cpcc.notify")

# More would be forgotten rather than used; revoking one makes room.
MAX_TOKENS_PER_USER = 100
NAME_MAX_CHARS = ApiToken._meta.get_field("name").max_length or 100


def api_token_create(*, user: User, name: str, role: str = "") -> tuple[ApiToken, str]:
    """Make a named token for the user: returns it and its key, which is never shown again.
    ``role``: what the token may do, at most what its user may (blank: its user's role, as
    that changes).

    Raises ValidationError on ``name`` for a blank name, one over 100 characters, one with a
    control or bidirectional formatting character, or one the user already gave a token (code
    ``unique``); on ``role`` for one that is not a role or is wider than the user's; and when
    the user already has MAX_TOKENS_PER_USER tokens.
    """
    name = name.strip()
    problem = _name_problem(name)
    if problem is not None:
        raise ValidationError({"name": problem})
    if role:
        if not roles.is_role(role):
            raise ValidationError(
                {"role": f"{role!r} is not a role; one of {', '.join(roles.CUSTOMER_ROLES)}."}
            )
        if user.customer_id is None:
            raise ValidationError({"role": "Only a customer's member's token carries a role."})
        if roles.narrower(user.role, role) != role:
            raise ValidationError(
                {"role": f"A token may do at most what you may: you are {user.role}."}
            )
    with transaction.atomic():
        # The user's row first: two requests at once cannot both take the last place.
        User.objects.select_for_update().filter(pk=user.pk).exists()
        if ApiToken.objects.filter(user=user).count() >= MAX_TOKENS_PER_USER:
            raise ValidationError(
                f"You have {MAX_TOKENS_PER_USER} API tokens, the most one may have: revoke one "
                "you no longer use first."
            )
        if ApiToken.objects.filter(user=user, name=name).exists():
            raise ValidationError({"name": _taken(name)})
        try:
            with transaction.atomic():
                token, key = ApiToken.objects.create(user=user, expiry=None, name=name, role=role)
        except IntegrityError:  # made meanwhile by another request of the same user
            raise ValidationError({"name": _taken(name)}) from None
    return token, key


def _name_problem(name: str) -> str | None:
    if not name:
        return 'Give the token a name, e.g. where it is used ("laptop", "CI").'
    if len(name) > NAME_MAX_CHARS:
        return f"A token's name has at most {NAME_MAX_CHARS} characters ({len(name)} given)."
    return plain_name_problem(name)


def _taken(name: str) -> ValidationError:
    return ValidationError(
        f"You already have a token named {name!r}: choose another name, or revoke that one.",
        code="unique",
    )


def api_token_revoke(*, token: ApiToken) -> None:
    """Revoke a token (one the caller selected for its owner): it is refused from now on."""
    token.delete()


def legacy_token_revoke(*, user: User) -> bool:
    """Revoke the token an administrator made for the user with ``drf_create_token``; False
    when the user has none."""
    token = legacy_token_for_user(user=user)
    if token is None:
        return False
    token.delete()
    return True


# Webhooks one customer may have.
MAX_WEBHOOKS_PER_CUSTOMER = 20
EVENTS = tuple(NotifyEvent.values)


# --- webhooks and e-mails: what the customer's people choose to hear of -----------------------


def webhook_create(
    *, customer: Customer, url: str, events: Sequence[str], allow_private: bool
) -> Webhook:
    """Add a webhook: ``url`` hears of ``events`` by a POST signed with a new secret (the
    returned webhook's ``secret``, to be shown to the customer once).

    Raises ValidationError on ``url`` for a URL that is not http(s), is too long, or whose
    host does not resolve or (unless ``allow_private``) has an address not on the public
    internet; one the customer already has (code ``unique``); on ``events`` for none or an
    unknown one; and when the customer has MAX_WEBHOOKS_PER_CUSTOMER webhooks.
    """
    url = url.strip()
    chosen = _events(events, field="events")
    if not chosen:
        raise ValidationError({"events": f"Choose at least one of {', '.join(EVENTS)}."})
    _check_url(url, allow_private=allow_private)
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=customer.pk)
        if customer.webhooks.count() >= MAX_WEBHOOKS_PER_CUSTOMER:
            raise ValidationError(
                f"You have {MAX_WEBHOOKS_PER_CUSTOMER} webhooks, the most one may have: remove "
                "one first (a webhook hears of several events)."
            )
        if customer.webhooks.filter(url=url).exists():
            raise ValidationError(
                {
                    "url": ValidationError(
                        "You already have a webhook for this URL: remove it first to change it.",
                        code="unique",
                    )
                }
            )
        webhook = Webhook.objects.create(
            customer=customer, url=url, events=chosen, secret=_new_secret()
        )
        _listen(customer)
    logger.info("webhook added", extra={"customer": customer.slug, "webhook": webhook.pk})
    return webhook


def _new_secret() -> str:
    return "whsec_" + secrets.token_hex(32)


def _check_url(url: str, *, allow_private: bool) -> None:
    max_length = Webhook._meta.get_field("url").max_length or 2000
    if len(url) > max_length:
        raise ValidationError({"url": f"A webhook URL has at most {max_length} characters."})
    if any(char.isspace() or ord(char) < 32 or ord(char) == 127 for char in url):
        raise ValidationError(
            {"url": "A URL has no spaces or control characters (percent-encode them)."}
        )
    try:
        delivery.check_url(url, allow_private=allow_private)
    except delivery.UnsafeURL as exc:
        raise ValidationError({"url": str(exc)}) from None


def _events(events: Sequence[str], *, field: str) -> list[str]:
    unknown = [e for e in events if e not in EVENTS]
    if unknown:
        raise ValidationError(
            {
                field: f"Unknown event(s) {', '.join(map(repr, unknown))}; events: {', '.join(EVENTS)}."
            }
        )
    return [e for e in EVENTS if e in events]  # in the usual order, each once


def webhook_delete(*, webhook: Webhook) -> None:
    """Remove a webhook (one the caller selected for its customer) with its delivery log;
    attempts under way end unsent."""
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=webhook.customer_id)
        webhook.delete()
        _listen(customer)


def user_set_email_events(*, user: User, email: str, events: Sequence[str]) -> User:
    """Set the address a customer's user gets e-mails at and the events it is e-mailed
    (none: no e-mail). Raises ValidationError on ``email`` for an address that is not one, or
    is missing while events are chosen; on ``email_events`` for an unknown event."""
    email = email.strip()
    chosen = _events(events, field="email_events")
    if email:
        try:
            EmailValidator()(email)
        except ValidationError:
            raise ValidationError({"email": f"{email!r} is not an e-mail address."}) from None
    elif chosen:
        raise ValidationError({"email": "Give the address the e-mails should go to."})
    if user.customer_id is None:
        raise ValidationError("Only a customer's users have VVs to hear about.")
    with transaction.atomic():
        customer = Customer.objects.select_for_update().get(pk=user.customer_id)
        user = User.objects.select_for_update().get(pk=user.pk)
        user.email = email
        user.email_events = chosen
        user.save(update_fields=["email", "email_events"])
        _listen(customer)
    return user


def _listen(customer: Customer) -> None:
    """Write which events someone of the customer listens for (its row held by the caller)."""
    events: set[str] = set()
    for chosen in Webhook.objects.filter(customer=customer).values_list("events", flat=True):
        events.update(chosen)
    users = User.objects.filter(customer=customer, is_active=True).exclude(email="")
    for chosen in users.values_list("email_events", flat=True):
        events.update(chosen)
    listened = [e for e in EVENTS if e in events]
    if listened != customer.notify_events:
        # An UPDATE of its own: no audit-log entry, no customer signal (Customer.save).
        Customer.objects.filter(pk=customer.pk).update(notify_events=listened)
        customer.notify_events = listened


# --- members: invitations, roles, removal -------------------------------------------------------

INVITE_SALT = "cpcc.invite"


class InviteInvalid(Exception):
    """A link that is no invitation, or one that expired, was used or was withdrawn: the
    message says which, in the invitee's words."""


def invite_create(
    *,
    customer: Customer,
    email: str,
    role: str,
    invited_by: User | None,
    link: Callable[[str], str],
) -> Invite:
    """Invite ``email`` to join ``customer`` as ``role``: the invitation is kept and e-mailed
    (through Django's mail settings) as a signed link, ``link(signed)``, that expires after
    ``CPCC_INVITE_DAYS`` and can be used once.

    Raises ValidationError on ``email`` for an address that is not one or a member's already,
    on ``role`` for one that is not a role."""
    email = email.strip()
    try:
        EmailValidator()(email)
    except ValidationError:
        raise ValidationError({"email": f"{email!r} is not an e-mail address."}) from None
    if not roles.is_role(role):
        raise ValidationError(
            {"role": f"{role!r} is not a role; one of {', '.join(roles.CUSTOMER_ROLES)}."}
        )
    if User.objects.filter(customer=customer, is_active=True, email__iexact=email).exists():
        raise ValidationError({"email": f"{email} is a member already."})
    now = timezone.now()
    invite = Invite.objects.create(
        customer=customer,
        email=email,
        role=role,
        invited_by=invited_by,
        created=now,
        expires=now + dt.timedelta(days=settings.CPCC_INVITE_DAYS),
    )
    signed = signing.dumps(invite.pk, salt=INVITE_SALT)
    who = invited_by.get_username() if invited_by is not None else "An owner"
    days = settings.CPCC_INVITE_DAYS
    send_mail(
        subject=f"[CPCC] {who} invites you to {customer.name}",
        message=(
            f"{who} invites you to join {customer.name} on CPCC as {role} "
            f"({roles.ROLE_LABELS[role]}).\n\nAccept within {days:g} days, once:\n"
            f"{link(signed)}\n\nIf you did not expect this, ignore this e-mail."
        ),
        from_email=None,
        recipient_list=[email],
    )
    logger.info(
        "member invited", extra={"customer": customer.slug, "invite": invite.pk, "role": role}
    )
    return invite


def invite_find(*, signed: str) -> Invite:
    """The open invitation a link names; InviteInvalid saying why there is none."""
    max_age = settings.CPCC_INVITE_DAYS * 86400
    try:
        pk = signing.loads(signed, salt=INVITE_SALT, max_age=max_age)
    except signing.SignatureExpired:
        raise InviteInvalid("This invitation expired: ask for a new one.") from None
    except signing.BadSignature:
        raise InviteInvalid("This link is not an invitation (it may be cut short).") from None
    invite = Invite.objects.select_related("customer").filter(pk=pk).first()
    if invite is None:
        raise InviteInvalid("This invitation was withdrawn: ask for a new one.")
    if invite.accepted is not None:
        raise InviteInvalid("This invitation was used already: log in instead.")
    if invite.expires <= timezone.now():
        raise InviteInvalid("This invitation expired: ask for a new one.")
    return invite


def invite_accept(*, signed: str, username: str, password: str) -> User:
    """Accept an invitation: a new user of its customer with its role and address, who can log
    in with ``username`` and ``password`` at once. Used once: a second accept (even at the same
    moment) raises InviteInvalid. Raises ValidationError on ``username`` for one in use or not
    valid, on ``password`` for one Django's validators refuse."""
    username = username.strip()
    if not username:
        raise ValidationError({"username": "Choose a user name."})
    try:
        User.username_validator(username)
    except ValidationError as exc:
        raise ValidationError({"username": exc.messages}) from None
    with transaction.atomic():
        invite = invite_find(signed=signed)
        invite = Invite.objects.select_for_update().get(pk=invite.pk)
        if invite.accepted is not None:
            raise InviteInvalid("This invitation was used already: log in instead.")
        if User.objects.filter(username__iexact=username).exists():
            raise ValidationError({"username": f"{username!r} is taken: choose another."})
        user = User(
            username=username, customer_id=invite.customer_id, role=invite.role, email=invite.email
        )
        try:
            validate_password(password, user)
        except ValidationError as exc:
            raise ValidationError({"password": exc.messages}) from None
        user.set_password(password)
        user.save()
        invite.accepted, invite.accepted_by = timezone.now(), user
        invite.save(update_fields=["accepted", "accepted_by"])
    logger.info(
        "invitation accepted",
        extra={"customer": invite.customer.slug, "invite": invite.pk, "user": user.pk},
    )
    return user


def invite_withdraw(*, invite: Invite) -> None:
    """Withdraw an invitation not used yet (one the caller selected for its customer): its link
    no longer works."""
    invite.delete()


def _other_owners(member: User) -> bool:
    return (
        User.objects.select_for_update()
        .filter(customer_id=member.customer_id, role=roles.OWNER, is_active=True)
        .exclude(pk=member.pk)
        .exists()
    )


def member_set_role(*, member: User, role: str) -> User:
    """Give a member (one the caller selected for its customer) another role; their tokens
    carry at most the new one. Raises ValidationError on ``role`` for one that is not a role,
    and for taking the role of owner from the customer's last owner."""
    if not roles.is_role(role):
        raise ValidationError(
            {"role": f"{role!r} is not a role; one of {', '.join(roles.CUSTOMER_ROLES)}."}
        )
    with transaction.atomic():
        member = User.objects.select_for_update().get(pk=member.pk)
        if member.role == roles.OWNER and role != roles.OWNER and not _other_owners(member):
            raise ValidationError(
                {"role": "The last owner stays owner: make another member owner first."}
            )
        member.role = role
        member.save(update_fields=["role"])
    return member


def member_remove(*, member: User) -> None:
    """Remove a member (one the caller selected for its customer): they can no longer log in
    and their API tokens die with them; their account is kept inactive for the records (the
    audit log names them). Raises ValidationError for the customer's last owner."""
    with transaction.atomic():
        member = User.objects.select_for_update().get(pk=member.pk)
        if member.role == roles.OWNER and not _other_owners(member):
            raise ValidationError("The last owner cannot be removed: make another member owner.")
        ApiToken.objects.filter(user=member).delete()
        legacy_token_revoke(user=member)
        member.is_active = False
        member.save(update_fields=["is_active"])
        customer = Customer.objects.select_for_update().get(pk=member.customer_id)
        _listen(customer)
    logger.info("member removed", extra={"customer": customer.slug, "user": member.pk})
