"""Limits on what one client can do: login attempts, request rates, request sizes."""

from __future__ import annotations

import pytest
from axes.models import AccessAttempt
from django.test import Client
from rest_framework.throttling import SimpleRateThrottle

from tests.api_fixtures import token_client


def login(client: Client, username: str, password: str) -> int:
    response = client.post("/accounts/login/", {"username": username, "password": password})
    return response.status_code


@pytest.mark.django_db
def test_logins_are_locked_after_five_failures_for_that_user_name(user_a, user_b) -> None:
    user_a.set_password("right-password-1")
    user_a.save()
    user_b.set_password("right-password-2")
    user_b.save()
    client = Client()
    for _ in range(4):
        assert login(client, "customer-a", "wrong") == 200  # the form again, with its error
    locked = client.post("/accounts/login/", {"username": "customer-a", "password": "wrong"})
    assert locked.status_code == 429
    assert b"Too many failed logins" in locked.content
    # Locked even with the right password now; another user from the same address is not.
    assert login(client, "customer-a", "right-password-1") == 429
    assert login(Client(), "customer-b", "right-password-2") == 302
    # An operator unlocks it (axes_reset, or the admin's "access attempts").
    AccessAttempt.objects.all().delete()
    assert login(Client(), "customer-a", "right-password-1") == 302


@pytest.mark.django_db
def test_api_requests_are_throttled_per_user_and_per_address(user_a, user_b, monkeypatch) -> None:
    monkeypatch.setattr(SimpleRateThrottle, "THROTTLE_RATES", {"user": "3/min", "address": "5/min"})
    a, b = token_client(user_a), token_client(user_b)
    assert [a.get("/api/v1/vvs/").status_code for _ in range(3)] == [200, 200, 200]
    refused = a.get("/api/v1/vvs/")
    assert refused.status_code == 429
    assert int(refused["Retry-After"]) > 0
    assert "throttled" in refused.json()["detail"].lower()
    # User B has requests left, but the address has one (A's four count, refused or not).
    assert [b.get("/api/v1/vvs/").status_code for _ in range(2)] == [200, 429]


@pytest.mark.django_db
def test_a_body_above_the_limit_is_refused_before_it_is_read(user_a, settings) -> None:
    api_a = token_client(user_a)
    settings.CPCC_MAX_REQUEST_BYTES = 100_000
    program = "var x = 1;\n" * 20_000  # 220 kB
    response = api_a.post("/api/v1/vvs/", {"name": "big", "program": program}, format="json")
    assert response.status_code == 413
    assert "at most 100,000" in response.json()["detail"]
    small = api_a.post("/api/v1/vvs/", {"name": "small", "program": "var x;"}, format="json")
    assert small.status_code != 413
