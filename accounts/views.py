"""The Account pages: a user's API tokens (make one, see when each was last used, revoke one),
and a customer's notifications (webhooks with their delivery logs, the e-mails each user
wants).

A key or a secret is shown once, in the answer to the POST that made it (never stored in the
session or a message, never cached: ``never_cache``). Each view reads through the scoped
selectors of accounts/selectors.py (another user's token, another customer's webhook: 404) and
changes state through one service.
"""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.exceptions import PermissionDenied, ValidationError
from django.core.paginator import Paginator
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.views.decorators.cache import never_cache
from django.views.decorators.http import require_GET, require_http_methods, require_POST

from accounts.forms import ApiTokenForm, EmailEventsForm, WebhookForm
from accounts.models import NotifyEvent, User, Webhook
from accounts.selectors import (
    ApiTokenNotFound,
    WebhookNotFound,
    api_token_get_for_user,
    api_token_list_for_user,
    legacy_token_for_user,
    webhook_deliveries_for_user,
    webhook_get_for_user,
    webhook_list_for_user,
)
from accounts.services import (
    api_token_create,
    api_token_revoke,
    legacy_token_revoke,
    user_set_email_events,
    webhook_create,
    webhook_delete,
)

# The newest attempts the Notifications page shows under each webhook; its own page has all.
ATTEMPTS_SHOWN = 5
ATTEMPTS_PER_PAGE = 50
NOT_A_CUSTOMER = "Webhooks and e-mails are about a customer's VVs: log in as one of its users."


def _user(request: HttpRequest) -> User:
    return request.user  # type: ignore[return-value]  # login_required


# --- API tokens -------------------------------------------------------------------------------


@never_cache
@login_required
@require_http_methods(["GET", "POST"])
def tokens(request: HttpRequest) -> HttpResponse:
    """The user's API tokens; a POST makes one and shows its key on this answer only."""
    form = ApiTokenForm(request.POST if request.method == "POST" else None)
    made: dict[str, Any] | None = None
    status = 200
    if request.method == "POST":
        if form.is_valid():
            try:
                token, key = api_token_create(user=_user(request), name=form.cleaned_data["name"])
            except ValidationError as exc:
                form.add_error(None, exc)
            else:
                made = {"token": token, "key": key}
                form = ApiTokenForm()
        if made is None:
            status = 400
    context = {
        "form": form,
        "made": made,
        "tokens": list(api_token_list_for_user(user=_user(request))),
        "legacy": legacy_token_for_user(user=_user(request)),
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


def _customer_user(request: HttpRequest) -> User:
    user = _user(request)
    if user.customer_id is None:
        raise PermissionDenied(NOT_A_CUSTOMER)
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
    """Add a webhook; its secret is shown on this answer only."""
    user = _customer_user(request)
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
    }
    return render(request, "accounts/notifications.html", context, status=status)


@login_required
@require_POST
def webhook_remove(request: HttpRequest, webhook_id: int) -> HttpResponse:
    """Remove one of the customer's webhooks with its delivery log."""
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
