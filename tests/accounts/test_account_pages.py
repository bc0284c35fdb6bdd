"""The Account pages: API tokens (make one, its key shown once, last used, revoke) and
notifications (webhooks with their delivery logs, e-mail choices), each user and customer on
their own."""

from __future__ import annotations

import re

import pytest
from django.test import Client
from rest_framework.authtoken.models import Token
from rest_framework.test import APIClient

from accounts.models import ApiToken, Customer, Webhook, WebhookDelivery
from accounts.services import webhook_create

pytestmark = pytest.mark.django_db

KEY = re.compile(r"cpcc_[0-9a-f]{64}")
SECRET = re.compile(r"whsec_[0-9a-f]{64}")


def logged_in(user) -> Client:
    client = Client()
    client.force_login(user)
    return client


def api_with(key: str) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    return client


def test_the_pages_ask_for_a_login_and_the_navigation_links_them(user_a) -> None:
    for path in ("/accounts/tokens/", "/accounts/notifications/"):
        answer = Client().get(path)
        assert answer.status_code == 302 and answer["Location"].startswith("/accounts/login/")
    home = logged_in(user_a).get("/").content.decode()
    assert '<a href="/accounts/tokens/">Account</a>' in home


def test_a_token_made_on_the_page_is_shown_once_works_and_is_revoked(user_a, settings) -> None:
    settings.CPCC_TOKEN_CACHE_S = 10.0
    browser = logged_in(user_a)
    made = browser.post("/accounts/tokens/", {"name": "laptop"})
    assert made.status_code == 200 and made["Cache-Control"].startswith("max-age=0")
    page = made.content.decode()
    keys = KEY.findall(page)
    assert len(set(keys)) == 1, "the new key is on the page"
    key = keys[0]
    token = ApiToken.objects.get(user=user_a)
    assert token.name == "laptop" and key.startswith(token.token_key)

    again = browser.get("/accounts/tokens/").content.decode()
    assert key not in again and f"{token.token_key}…" in again and "never" in again

    assert api_with(key).get("/api/v1/vvs/").status_code == 200
    assert "ago</time>" in browser.get("/accounts/tokens/").content.decode()

    revoked = browser.post(f"/accounts/tokens/{token.pk}/revoke/", follow=True)
    assert "The token “laptop” is revoked" in revoked.content.decode()
    assert not ApiToken.objects.exists()
    assert api_with(key).get("/api/v1/vvs/").status_code == 401


def test_a_bad_name_is_refused_on_the_page(user_a) -> None:
    browser = logged_in(user_a)
    browser.post("/accounts/tokens/", {"name": "CI"})
    again = browser.post("/accounts/tokens/", {"name": "CI"})
    assert again.status_code == 400
    assert "You already have a token named &#x27;CI&#x27;" in again.content.decode()
    assert not KEY.search(again.content.decode())
    assert ApiToken.objects.count() == 1


def test_another_users_token_cannot_be_revoked(user_a, user_b) -> None:
    logged_in(user_a).post("/accounts/tokens/", {"name": "a's own laptop"})
    token = ApiToken.objects.get()
    assert logged_in(user_b).post(f"/accounts/tokens/{token.pk}/revoke/").status_code == 404
    assert ApiToken.objects.filter(pk=token.pk).exists()
    page = logged_in(user_b).get("/accounts/tokens/").content.decode()
    assert "own laptop" not in page and token.token_key not in page


def test_the_operators_token_is_listed_and_can_be_revoked(user_a) -> None:
    legacy = Token.objects.create(user=user_a)
    browser = logged_in(user_a)
    page = browser.get("/accounts/tokens/").content.decode()
    assert "made by the operator" in page and legacy.key not in page
    browser.post("/accounts/tokens/operator/revoke/")
    assert not Token.objects.filter(user=user_a).exists()
    assert api_with(legacy.key).get("/api/v1/vvs/").status_code == 401


def test_a_webhook_added_on_the_page_shows_its_secret_once(user_a, settings) -> None:
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True
    browser = logged_in(user_a)
    made = browser.post(
        "/accounts/webhooks/new/",
        {"url": "http://127.0.0.1:9/hook", "events": ["vv.finished", "task.done"]},
    )
    assert made.status_code == 200
    webhook = Webhook.objects.get()
    assert SECRET.findall(made.content.decode()) == [webhook.secret]
    assert webhook.events == ["vv.finished", "task.done"]
    page = browser.get("/accounts/notifications/").content.decode()
    assert "http://127.0.0.1:9/hook" in page and webhook.secret not in page
    assert Customer.objects.get(pk=user_a.customer_id).notify_events == [
        "vv.finished",
        "task.done",
    ]


def test_a_private_address_is_refused_on_the_page_without_the_setting(user_a) -> None:
    refused = logged_in(user_a).post(
        "/accounts/webhooks/new/", {"url": "http://localhost:8000/hook", "events": ["vv.failed"]}
    )
    assert refused.status_code == 400
    assert "is a loopback address" in refused.content.decode()
    assert not Webhook.objects.exists()


def test_a_webhooks_delivery_log_is_its_customers_only(user_a, user_b, settings) -> None:
    webhook = webhook_create(
        customer=user_a.customer,
        url="http://127.0.0.1:9/hook",
        events=["vv.failed"],
        allow_private=True,
    )
    WebhookDelivery.objects.create(
        webhook=webhook,
        event="vv.failed",
        vv_id="00000000-0000-0000-0000-000000000001",
        attempt=1,
        status_code=None,
        error="connection refused",
    )
    log = logged_in(user_a).get(f"/accounts/webhooks/{webhook.pk}/")
    assert log.status_code == 200 and "connection refused" in log.content.decode()
    other = logged_in(user_b)
    assert other.get(f"/accounts/webhooks/{webhook.pk}/").status_code == 404
    assert other.post(f"/accounts/webhooks/{webhook.pk}/remove/").status_code == 404
    assert "127.0.0.1:9" not in other.get("/accounts/notifications/").content.decode()
    logged_in(user_a).post(f"/accounts/webhooks/{webhook.pk}/remove/")
    assert not Webhook.objects.exists() and not WebhookDelivery.objects.exists()


def test_a_user_chooses_the_emails_it_gets(user_a) -> None:
    browser = logged_in(user_a)
    refused = browser.post("/accounts/notifications/", {"email": "", "email_events": ["vv.failed"]})
    assert refused.status_code == 400 and "Give the address" in refused.content.decode()
    saved = browser.post(
        "/accounts/notifications/",
        {"email": "a@example.com", "email_events": ["vv.failed"]},
        follow=True,
    )
    assert "Saved: an e-mail to a@example.com when a VV failed or was killed." in (
        saved.content.decode()
    )
    user_a.refresh_from_db()
    assert (user_a.email, user_a.email_events) == ("a@example.com", ["vv.failed"])
    assert Customer.objects.get(pk=user_a.customer_id).notify_events == ["vv.failed"]
    browser.post("/accounts/notifications/", {"email": "a@example.com"})
    assert Customer.objects.get(pk=user_a.customer_id).notify_events == []


def test_staff_have_tokens_but_no_notifications(staff) -> None:
    browser = logged_in(staff)
    assert browser.get("/accounts/tokens/").status_code == 200
    page = browser.get("/accounts/notifications/").content.decode()
    assert "log in as one of its users" in page
    refused = browser.post(
        "/accounts/webhooks/new/", {"url": "https://example.com/", "events": ["vv.failed"]}
    )
    assert refused.status_code == 403
