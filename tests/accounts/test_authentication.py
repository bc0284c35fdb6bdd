"""API token lookups answered from the web process's cache (accounts/authentication.py): no
query for a token seen recently, a revoked token refused at once in the process that revoked
it and within the TTL elsewhere."""

from __future__ import annotations

import pytest
from django.core.management import call_command
from django.db import connection
from django.test.utils import CaptureQueriesContext
from rest_framework.authtoken.models import Token
from rest_framework.test import APIClient

from accounts.authentication import TOKENS, token_digest
from vvm_worker.services import vv_submit

pytestmark = pytest.mark.django_db

URL = "/api/v1/vvs/"


class Clock:
    """The cache's clock, moved by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch) -> Clock:
    stepped = Clock()
    monkeypatch.setattr(TOKENS, "_clock", stepped)
    return stepped


@pytest.fixture
def ttl_s(settings) -> float:
    settings.CPCC_TOKEN_CACHE_S = 10.0
    return 10.0


def client_for(key: str) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    return client


def token_queries(captured: CaptureQueriesContext) -> list[str]:
    return [q["sql"] for q in captured.captured_queries if "authtoken_token" in q["sql"]]


def test_a_token_seen_recently_is_not_looked_up_again(
    user_a, user_b, ttl_s, clock, vvm_factory
) -> None:
    key_a = Token.objects.create(user=user_a).key
    key_b = Token.objects.create(user=user_b).key
    vv_submit(customer=user_a.customer, name="a's", program="VV.log(1);", vvm=vvm_factory())
    with CaptureQueriesContext(connection) as first:
        assert client_for(key_a).get(URL).status_code == 200
    assert len(token_queries(first)) == 1
    # Its user and customer came with the token, in that one query.
    assert "accounts_customer" in token_queries(first)[0]
    with CaptureQueriesContext(connection) as again:
        answer = client_for(key_a).get(URL)
    assert answer.status_code == 200 and token_queries(again) == []
    assert [vv["name"] for vv in answer.json()["results"]] == ["a's"]
    # The other customer's token is its own entry: it sees its own VVs, none of A's.
    assert client_for(key_b).get(URL).json()["results"] == []
    assert client_for(key_a).get(URL).json()["count"] == 1
    # Each request gets a user object of its own.
    assert TOKENS.get(token_digest(key_a))[0] is not TOKENS.get(token_digest(key_a))[0]
    # Past the TTL the token is read again.
    clock.now += ttl_s + 0.1
    with CaptureQueriesContext(connection) as expired:
        assert client_for(key_a).get(URL).status_code == 200
    assert len(token_queries(expired)) == 1


def test_a_deleted_token_is_refused_at_once_in_the_process_that_deleted_it(
    user_a, user_b, ttl_s, clock
) -> None:
    token = Token.objects.create(user=user_a)
    other = Token.objects.create(user=user_b).key
    for key in (token.key, other):
        assert client_for(key).get(URL).status_code == 200
    token.delete()
    refused = client_for(token.key).get(URL)
    assert refused.status_code == 401 and refused.json()["detail"] == "Invalid token."
    assert client_for(other).get(URL).status_code == 200  # B's stays


def test_a_rotated_token_is_refused_and_the_new_one_works(user_a, ttl_s, clock) -> None:
    old = Token.objects.create(user=user_a).key
    assert client_for(old).get(URL).status_code == 200
    call_command("drf_create_token", "-r", user_a.username, stdout=None)
    new = Token.objects.get(user=user_a).key
    assert new != old
    assert client_for(old).get(URL).status_code == 401
    assert client_for(new).get(URL).status_code == 200


def test_a_deactivated_or_deleted_user_is_refused_at_once(user_a, user_b, ttl_s, clock) -> None:
    key_a = Token.objects.create(user=user_a).key
    key_b = Token.objects.create(user=user_b).key
    for key in (key_a, key_b):
        assert client_for(key).get(URL).status_code == 200
    user_a.is_active = False
    user_a.save()
    assert client_for(key_a).get(URL).status_code == 401
    user_b.delete()  # its token goes with it
    assert client_for(key_b).get(URL).status_code == 401


def test_a_changed_customer_is_read_again(user_a, customer_a, ttl_s, clock) -> None:
    key = Token.objects.create(user=user_a).key
    assert client_for(key).get(URL).status_code == 200
    assert len(TOKENS) == 1
    customer_a.max_queued_vvs = 1
    customer_a.save()
    assert len(TOKENS) == 0


def test_a_token_revoked_in_another_process_stops_working_within_the_ttl(
    user_a, ttl_s, clock
) -> None:
    key = Token.objects.create(user=user_a).key
    assert client_for(key).get(URL).status_code == 200
    # Another process deletes it: this one hears nothing of it.
    with connection.cursor() as cursor:
        cursor.execute("DELETE FROM authtoken_token WHERE key = %s", [key])
    clock.now += ttl_s - 1
    assert client_for(key).get(URL).status_code == 200  # still in this process's cache
    clock.now += 1
    assert client_for(key).get(URL).status_code == 401


def test_a_lookup_under_way_while_a_token_is_revoked_is_not_kept(user_a, ttl_s, clock) -> None:
    token = Token.objects.create(user=user_a)
    digest = token_digest(token.key)
    seen = TOKENS.generation  # a lookup begins, and reads the token...
    token.delete()  # ...meanwhile another thread of this process revokes it
    TOKENS.put(digest, user_a, token, ttl_s=ttl_s, generation=seen)
    assert len(TOKENS) == 0


def test_no_cache_with_a_ttl_of_zero(user_a, settings) -> None:
    settings.CPCC_TOKEN_CACHE_S = 0
    key = Token.objects.create(user=user_a).key
    for _ in range(2):
        with CaptureQueriesContext(connection) as captured:
            assert client_for(key).get(URL).status_code == 200
        assert len(token_queries(captured)) == 1
    assert len(TOKENS) == 0
