"""Named API tokens over the REST API (/api/v1/tokens/): a customer makes one (the key shown
once), uses it, sees when it was last used, revokes it and is refused at once; another user's
token is not found; a token cannot make another."""

from __future__ import annotations

import hashlib
import re

import pytest
from django.db import connection
from django.test.utils import CaptureQueriesContext
from rest_framework.authtoken.models import Token
from rest_framework.test import APIClient

from accounts.authentication import LAST_USED, TOKENS
from accounts.models import ApiToken

pytestmark = pytest.mark.django_db

TOKENS_URL = "/api/v1/tokens/"
VVS_URL = "/api/v1/vvs/"
KEY = re.compile(r"^cpcc_[0-9a-f]{64}$")


def logged_in(user) -> APIClient:
    """A client logged in with a password (a session), as the browser is."""
    client = APIClient()
    client.force_login(user)
    return client


def with_key(key: str) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    return client


@pytest.fixture
def cache_on(settings) -> None:
    settings.CPCC_TOKEN_CACHE_S = 10.0


def make(user, name: str = "laptop") -> dict:
    answer = logged_in(user).post(TOKENS_URL, {"name": name}, format="json")
    assert answer.status_code == 201, answer.json()
    return answer.json()


def test_a_customer_makes_a_token_uses_it_revokes_it_and_is_refused_at_once(
    user_a, cache_on
) -> None:
    made = make(user_a, "laptop")
    key = made["key"]
    assert KEY.match(key)
    assert made["name"] == "laptop" and made["prefix"] == key[:15] and made["last_used"] is None
    # Only a digest is stored (knox's SHA-512 of the key), never the key.
    stored = ApiToken.objects.get(pk=made["id"])
    assert stored.digest == hashlib.sha512(key.encode()).hexdigest()
    assert key not in {stored.digest, stored.token_key, stored.name}
    # The key is in the answer to its making only.
    session = logged_in(user_a)
    listed = session.get(TOKENS_URL).json()["results"]
    assert [t["name"] for t in listed] == ["laptop"] and "key" not in listed[0]
    assert "key" not in session.get(f"{TOKENS_URL}{made['id']}/").json()

    client = with_key(key)
    assert client.get(VVS_URL).status_code == 200
    assert client.get(VVS_URL).status_code == 200  # answered from the cache this time
    assert session.get(f"{TOKENS_URL}{made['id']}/").json()["last_used"] is not None

    assert session.delete(f"{TOKENS_URL}{made['id']}/").status_code == 204
    refused = client.get(VVS_URL)
    assert refused.status_code == 401 and refused.json()["detail"] == "Invalid token."
    assert session.get(TOKENS_URL).json()["results"] == []


def test_a_token_can_revoke_itself(user_a, cache_on) -> None:
    made = make(user_a)
    client = with_key(made["key"])
    assert client.delete(f"{TOKENS_URL}{made['id']}/").status_code == 204
    assert client.get(VVS_URL).status_code == 401


def test_a_token_cannot_revoke_its_users_other_tokens(user_a, cache_on) -> None:
    # A token that leaked cannot lock out every other integration of its user.
    laptop, ci = make(user_a, "laptop"), make(user_a, "CI")
    legacy = Token.objects.create(user=user_a).key
    for key in (laptop["key"], legacy):
        refused = with_key(key).delete(f"{TOKENS_URL}{ci['id']}/")
        assert refused.status_code == 403
        assert refused.json()["detail"].startswith("An API token can revoke only itself")
    assert with_key(ci["key"]).get(VVS_URL).status_code == 200
    assert sorted(ApiToken.objects.values_list("name", flat=True)) == ["CI", "laptop"]
    # With a session (logged in with the password) any of the user's tokens.
    assert logged_in(user_a).delete(f"{TOKENS_URL}{ci['id']}/").status_code == 204
    assert with_key(ci["key"]).get(VVS_URL).status_code == 401


def test_another_users_token_is_not_found_and_keeps_working(user_a, user_b, cache_on) -> None:
    made = make(user_a)
    other = logged_in(user_b)
    for method in ("get", "delete"):
        answer = getattr(other, method)(f"{TOKENS_URL}{made['id']}/")
        assert answer.status_code == 404, method
        assert answer.json()["detail"].startswith("No API token with this id among yours")
    assert other.get(TOKENS_URL).json()["results"] == []
    assert with_key(made["key"]).get(VVS_URL).status_code == 200
    assert logged_in(user_a).get(f"{TOKENS_URL}nope/").status_code == 404


def test_a_token_cannot_make_another(user_a) -> None:
    made = make(user_a)
    for client in (with_key(made["key"]), with_key(Token.objects.create(user=user_a).key)):
        refused = client.post(TOKENS_URL, {"name": "more"}, format="json")
        assert refused.status_code == 403
        assert "cannot make another" in refused.json()["detail"]
    assert list(ApiToken.objects.values_list("name", flat=True)) == ["laptop"]


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("   ", "This field may not be blank."),
        ("x" * 101, "Ensure this field has no more than 100 characters."),
        ("ci\x1b[31m", "control character"),
        (7, "Expected a string, got int: 7."),
    ],
)
def test_a_bad_name_is_refused_saying_why(user_a, name, problem) -> None:
    answer = logged_in(user_a).post(TOKENS_URL, {"name": name}, format="json")
    assert answer.status_code == 400
    assert problem in answer.json()["name"][0]
    assert not ApiToken.objects.exists()


def test_a_name_is_used_once_per_user(user_a, user_b) -> None:
    make(user_a, "CI")
    again = logged_in(user_a).post(TOKENS_URL, {"name": " CI "}, format="json")
    assert again.status_code == 409
    assert again.json()["name"] == [
        "You already have a token named 'CI': choose another name, or revoke that one."
    ]
    make(user_b, "CI")  # another user's names are their own


def test_last_used_is_written_at_most_once_a_minute(user_a, monkeypatch) -> None:
    made = make(user_a)
    client = with_key(made["key"])

    def writes(requests: int) -> int:
        with CaptureQueriesContext(connection) as seen:
            for _ in range(requests):
                assert client.get(VVS_URL).status_code == 200
        return sum(
            q["sql"].startswith("UPDATE") and "accounts_apitoken" in q["sql"]
            for q in seen.captured_queries
        )

    assert writes(5) == 1
    first = ApiToken.objects.get(pk=made["id"]).last_used
    assert first is not None
    # A minute later (this process's clock, and the row's time) it is written again.
    now = LAST_USED._clock()
    monkeypatch.setattr(LAST_USED, "_clock", lambda: now + 61)
    ApiToken.objects.filter(pk=made["id"]).update(last_used=first.replace(year=first.year - 1))
    assert writes(3) == 1
    assert ApiToken.objects.get(pk=made["id"]).last_used > first


def test_a_named_token_is_looked_up_once_with_its_user_and_customer(user_a, cache_on) -> None:
    made = make(user_a)
    client = with_key(made["key"])
    with CaptureQueriesContext(connection) as first:
        assert client.get(VVS_URL).status_code == 200
    lookups = [q["sql"] for q in first.captured_queries if 'FROM "accounts_apitoken"' in q["sql"]]
    assert len(lookups) == 1 and "accounts_customer" in lookups[0]
    with CaptureQueriesContext(connection) as again:
        assert client.get(VVS_URL).status_code == 200
    assert not [q for q in again.captured_queries if "accounts_apitoken" in q["sql"]]
    assert len(TOKENS) == 1


def test_the_operators_tokens_keep_working_beside_named_ones(user_a, cache_on) -> None:
    legacy = Token.objects.create(user=user_a).key
    made = make(user_a)
    for key in (legacy, made["key"]):
        assert with_key(key).get(VVS_URL).status_code == 200
    assert with_key("cpcc_" + "0" * 64).get(VVS_URL).status_code == 401
