"""The Account pages: a user's API tokens (make one, see when each was last used, revoke one),
a customer's notifications (webhooks with their delivery logs, the e-mails each user wants) and
its members (who, with which role; owners invite, change roles, remove).

What a member may do follows their role (accounts.roles): their own password, tokens and e-mail
choice are anyone's; webhooks need a developer, the members an owner. A refusal (403, saying
which role it needs) is decided before any object is looked up, so it says nothing of whether
one exists; another customer's object is 404 to whoever may ask.

A key or a secret is shown once, in the answer to the POST that made it (never stored in the
session or a message, never cached: ``never_cache``). Each view reads through the scoped
selectors of accounts/selectors.py (another user's token, another customer's webhook: 404) and
changes state through one service.
"""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.contrib import messages
from django.contrib.auth import login
from django.contrib.auth.decorators import login_required
from django.core.exceptions import PermissionDenied, ValidationError
from django.core.paginator import Paginator
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.urls import reverse
from django.views.decorators.cache import never_cache
from django.views.decorators.http import require_GET, require_http_methods, require_POST

from accounts.forms import (
    ApiTokenForm,
    EmailEventsForm,
    InviteAcceptForm,
    InviteForm,
    MemberRoleForm,
    WebhookForm,
)
from accounts.models import NotifyEvent, User, Webhook
from accounts.roles import CUSTOMER_ROLES, DEVELOPER, OWNER, ROLE_LABELS, narrower
from accounts.selectors import (
    ApiTokenNotFound,
    InviteNotFound,
    MemberNotFound,
    WebhookNotFound,
    api_token_get_for_user,
    api_token_list_for_user,
    invite_get_for_user,
    invite_list_for_user,
    legacy_token_for_user,
    member_get_for_user,
    member_list_for_user,
    webhook_deliveries_for_user,
    webhook_get_for_user,
    webhook_list_for_user,
)
from accounts.services import (
    InviteInvalid,
    api_token_create,
    api_token_revoke,
    invite_create,
    invite_find,
    invite_withdraw,
    legacy_token_revoke,
    member_remove,
    member_set_role,
    user_set_email_events,
    webhook_create,
    webhook_delete,
)
from accounts.services import invite_accept as invite_accept_service
from cpcc_site.permissions import acting_role, member_refusal

# The newest attempts the Notifications page shows under each webhook; its own page has all.
ATTEMPTS_SHOWN = 5
ATTEMPTS_PER_PAGE = 50
NOT_A_CUSTOMER = "Webhooks and e-mails are about a customer's VVs: log in as one of its users."
NO_MEMBERS = "Members belong to a customer: log in as one of its users."


def _user(request: HttpRequest) -> User:
    return request.user  # type: ignore[return-value]  # login_required


def _require_role(request: HttpRequest, needed: str, action: str) -> None:
    """403 with the refusal's sentence for a member whose role is below ``needed`` (asked
    before any object is looked up)."""
    why = member_refusal(request.user, None, needed, action)
    if why is not None:
        raise PermissionDenied(why)


def _may(request: HttpRequest, needed: str) -> bool:
    """Whether the pages offer the user what needs ``needed`` (a member of a customer with
    that role or higher)."""
    user = _user(request)
    return user.customer_id is not None and member_refusal(user, None, needed) is None


# --- API tokens -------------------------------------------------------------------------------


@never_cache
@login_required
@require_http_methods(["GET", "POST"])
def tokens(request: HttpRequest) -> HttpResponse:
    """The user's API tokens, each with the role it acts with; a POST makes one (acting with
    the user's role, or a narrower one chosen) and shows its key on this answer only. Anyone's
    own: a viewer makes tokens too, that read only."""
    user = _user(request)
    role = acting_role(user)
    form = ApiTokenForm(request.POST if request.method == "POST" else None, user_role=role)
    made: dict[str, Any] | None = None
    status = 200
    if request.method == "POST":
        if form.is_valid():
            try:
                token, key = api_token_create(
                    user=user, name=form.cleaned_data["name"], role=form.cleaned_data["role"]
                )
            except ValidationError as exc:
                form.add_error(None, exc)
            else:
                made = {"token": token, "key": key}
                form = ApiTokenForm(user_role=role)
        if made is None:
            status = 400
    tokens = list(api_token_list_for_user(user=user))
    for token in tokens:
        # What it may do now: its own role, at most its user's (blank: its user's).
        token.acts_as = narrower(role, token.role) if role else ""  # type: ignore[attr-defined]
    context = {
        "form": form,
        "made": made,
        "tokens": tokens,
        "role": role,
        "legacy": legacy_token_for_user(user=user),
        "api_url": request.build_absolute_uri("/"),
    }
    return render(request, "accounts/tokens.html", context, status=status)


@login_required
@require_POST
def token_revoke(request: HttpRequest, token_id: int) -> HttpResponse:
    """Revoke one of the user's tokens: refused from now on."""
    try:
        token = api_token_get_for_user(user=_user(request), token_id=token_id)
    except ApiTokenNotFound:
        raise Http404("No such API token among yours.") from None
    api_token_revoke(token=token)
    messages.success(request, f"The token “{token.name}” is revoked: it no longer works.")
    return redirect("account-tokens")


@login_required
@require_POST
def legacy_token_revoke_view(request: HttpRequest) -> HttpResponse:
    """Revoke the token an administrator made for the user."""
    if legacy_token_revoke(user=_user(request)):
        messages.success(request, "The token the operator made for you is revoked.")
    return redirect("account-tokens")


# --- notifications ----------------------------------------------------------------------------


def _customer_user(request: HttpRequest, why: str = NOT_A_CUSTOMER) -> User:
    user = _user(request)
    if user.customer_id is None:
        raise PermissionDenied(why)
    return user


@never_cache
@login_required
@require_http_methods(["GET", "POST"])
def notifications(request: HttpRequest) -> HttpResponse:
    """The customer's webhooks (each with its newest attempts) and the e-mails this user
    wants; a POST saves the e-mail choice."""
    user = _user(request)
    email_form = EmailEventsForm(
        request.POST if request.method == "POST" else None,
        initial={"email": user.email, "email_events": user.email_events},
    )
    if request.method == "POST":
        user = _customer_user(request)
        if email_form.is_valid():
            try:
                user_set_email_events(
                    user=user,
                    email=email_form.cleaned_data["email"],
                    events=email_form.cleaned_data["email_events"],
                )
            except ValidationError as exc:
                email_form.add_error(None, exc)
            else:
                messages.success(request, _email_saved(email_form.cleaned_data))
                return redirect("account-notifications")
        return _notifications(request, email_form=email_form, status=400)
    return _notifications(request, email_form=email_form)


def _email_saved(chosen: dict[str, Any]) -> str:
    events = chosen["email_events"]
    if not events:
        return "Saved: no e-mails."
    labels = ", ".join(str(NotifyEvent(e).label) for e in events)
    return f"Saved: an e-mail to {chosen['email']} when {labels}."


@never_cache
@login_required
@require_POST
def webhook_new(request: HttpRequest) -> HttpResponse:
    """Add a webhook (a developer's); its secret is shown on this answer only."""
    user = _customer_user(request)
    _require_role(request, DEVELOPER, "a new webhook")
    form = WebhookForm(request.POST)
    if form.is_valid():
        try:
            webhook = webhook_create(
                customer=user.customer,  # type: ignore[arg-type]
                url=form.cleaned_data["url"],
                events=form.cleaned_data["events"],
                allow_private=settings.CPCC_WEBHOOK_ALLOW_PRIVATE,
            )
        except ValidationError as exc:
            form.add_error(None, exc)
        else:
            return _notifications(request, made=webhook)
    return _notifications(request, webhook_form=form, status=400)


def _notifications(
    request: HttpRequest,
    *,
    webhook_form: WebhookForm | None = None,
    email_form: EmailEventsForm | None = None,
    made: Webhook | None = None,
    status: int = 200,
) -> HttpResponse:
    user = _user(request)
    webhooks = list(webhook_list_for_user(user=user))
    for webhook in webhooks:
        webhook.recent = list(  # type: ignore[attr-defined]
            webhook_deliveries_for_user(user=user, webhook_id=webhook.pk)[:ATTEMPTS_SHOWN]
        )
    context = {
        "is_customer": user.customer_id is not None,
        "webhooks": webhooks,
        "made": made,
        "webhook_form": webhook_form or WebhookForm(),
        "email_form": email_form
        or EmailEventsForm(initial={"email": user.email, "email_events": user.email_events}),
        "allow_private": settings.CPCC_WEBHOOK_ALLOW_PRIVATE,
        # A viewer reads the webhooks and chooses their own e-mails; a developer changes them.
        "may_change_webhooks": _may(request, DEVELOPER),
    }
    return render(request, "accounts/notifications.html", context, status=status)


@login_required
@require_POST
def webhook_remove(request: HttpRequest, webhook_id: int) -> HttpResponse:
    """Remove one of the customer's webhooks with its delivery log (a developer's)."""
    _require_role(request, DEVELOPER, "a webhook's removal")
    try:
        webhook = webhook_get_for_user(user=_user(request), webhook_id=webhook_id)
    except WebhookNotFound:
        raise Http404("No such webhook among yours.") from None
    webhook_delete(webhook=webhook)
    messages.success(request, f"The webhook to {webhook.url} is removed.")
    return redirect("account-notifications")


@login_required
@require_GET
def webhook_detail(request: HttpRequest, webhook_id: int) -> HttpResponse:
    """One webhook's delivery log, newest first."""
    user = _user(request)
    try:
        webhook = webhook_get_for_user(user=user, webhook_id=webhook_id)
    except WebhookNotFound:
        raise Http404("No such webhook among yours.") from None
    attempts = webhook_deliveries_for_user(user=user, webhook_id=webhook.pk)
    page = Paginator(attempts, ATTEMPTS_PER_PAGE).get_page(request.GET.get("page"))
    return render(request, "accounts/webhook.html", {"webhook": webhook, "page": page})


# --- members ------------------------------------------------------------------------------------


@never_cache
@login_required
@require_http_methods(["GET", "HEAD", "POST"])
def members(request: HttpRequest) -> HttpResponse:
    """The customer's members with their roles and its open invitations, for every member; an
    owner also invites (a POST: the invitation goes out by e-mail), changes roles and removes
    members."""
    if request.method != "POST":
        return _members(request, InviteForm())
    user = _customer_user(request, NO_MEMBERS)
    _require_role(request, OWNER, "an invitation")
    form = InviteForm(request.POST)
    if form.is_valid():
        try:
            invite = invite_create(
                customer=user.customer,  # type: ignore[arg-type]
                email=form.cleaned_data["email"],
                role=form.cleaned_data["role"],
                invited_by=user,
                link=lambda signed: request.build_absolute_uri(
                    reverse("account-invite", args=[signed])
                ),
            )
        except ValidationError as exc:
            _add_errors(form, exc)
        else:
            messages.success(
                request,
                f"The invitation is sent to {invite.email} (as {invite.role}); its link works "
                f"once, until {invite.expires:%Y-%m-%d %H:%M} UTC.",
            )
            return redirect("account-members")
    return _members(request, form, status=400)


def _add_errors(form: InviteForm, exc: ValidationError) -> None:
    if not hasattr(exc, "error_dict"):
        form.add_error(None, exc)
        return
    for field, problems in exc.message_dict.items():
        for problem in problems:
            form.add_error(field if field in form.fields else None, problem)


def _members(request: HttpRequest, form: InviteForm, *, status: int = 200) -> HttpResponse:
    user = _user(request)
    context = {
        "is_customer": user.customer_id is not None,
        "members": list(member_list_for_user(user=user)),
        "invites": list(invite_list_for_user(user=user).select_related("invited_by")),
        "form": form,
        "is_owner": _may(request, OWNER),
        # The most allowed first, as the invitation's choices.
        "roles": [(role, ROLE_LABELS[role]) for role in reversed(CUSTOMER_ROLES)],
        "invite_days": f"{settings.CPCC_INVITE_DAYS:g}",
    }
    return render(request, "accounts/members.html", context, status=status)


@login_required
@require_POST
def member_role(request: HttpRequest, member_id: int) -> HttpResponse:
    """Give one of the customer's members another role (an owner's)."""
    _require_role(request, OWNER, "a change of a member's role")
    try:
        member = member_get_for_user(user=_user(request), member_id=member_id)
    except MemberNotFound:
        raise Http404("No such member of your customer.") from None
    form = MemberRoleForm(request.POST)
    if not form.is_valid():
        messages.error(request, f"Choose a role: one of {', '.join(CUSTOMER_ROLES)}.")
        return redirect("account-members")
    try:
        member = member_set_role(member=member, role=form.cleaned_data["role"])
    except ValidationError as exc:
        messages.error(request, " ".join(exc.messages))
    else:
        messages.success(request, f"{member.get_username()} is now {member.role}.")
    return redirect("account-members")


@login_required
@require_POST
def member_remove_view(request: HttpRequest, member_id: int) -> HttpResponse:
    """Remove one of the customer's members (an owner's): they can no longer log in and their
    API tokens stop working."""
    _require_role(request, OWNER, "a member's removal")
    try:
        member = member_get_for_user(user=_user(request), member_id=member_id)
    except MemberNotFound:
        raise Http404("No such member of your customer.") from None
    try:
        member_remove(member=member)
    except ValidationError as exc:
        messages.error(request, " ".join(exc.messages))
    else:
        messages.success(
            request,
            f"{member.get_username()} is removed: they can no longer log in, and their API "
            "tokens no longer work.",
        )
    return redirect("account-members")


@login_required
@require_POST
def invite_withdraw_view(request: HttpRequest, invite_id: int) -> HttpResponse:
    """Withdraw one of the customer's invitations not used yet (an owner's): its link no longer
    works."""
    _require_role(request, OWNER, "an invitation's withdrawal")
    try:
        invite = invite_get_for_user(user=_user(request), invite_id=invite_id)
    except InviteNotFound:
        raise Http404("No such invitation of your customer.") from None
    invite_withdraw(invite=invite)
    messages.success(
        request, f"The invitation to {invite.email} is withdrawn: its link no longer works."
    )
    return redirect("account-members")


# --- an invitation's link -----------------------------------------------------------------------


@never_cache
@require_http_methods(["GET", "HEAD", "POST"])
def invite_accept(request: HttpRequest, signed: str) -> HttpResponse:
    """The page an invitation's link opens (no login): who invites whom to which customer,
    and a form for the new account; accepting logs the new member in. A link that expired,
    was used or was withdrawn says so (410)."""
    try:
        invite = invite_find(signed=signed)
    except InviteInvalid as exc:
        return render(request, "accounts/invite.html", {"problem": str(exc)}, status=410)
    form = InviteAcceptForm(request.POST or None)
    if request.method == "POST" and form.is_valid():
        try:
            member = invite_accept_service(
                signed=signed,
                username=form.cleaned_data["username"],
                password=form.cleaned_data["password"],
            )
        except InviteInvalid as exc:
            return render(request, "accounts/invite.html", {"problem": str(exc)}, status=410)
        except ValidationError as exc:
            for field, problems in exc.message_dict.items():
                for problem in problems:
                    form.add_error(field if field in form.fields else None, problem)
        else:
            login(request, member, backend="django.contrib.auth.backends.ModelBackend")
            messages.success(
                request, f"Welcome to {invite.customer.name}: you are a {member.role}."
            )
            return redirect("home")
    context = {"invite": invite, "form": form, "role_label": ROLE_LABELS[invite.role]}
    return render(request, "accounts/invite.html", context)
