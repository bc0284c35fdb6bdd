"""A customer's members over the API (issue 57): invitations by e-mail (accepted, expired,
used twice, withdrawn), roles changed and narrowed by tokens, members removed with their
tokens. (Every route as every role: tests/cpcc_site/test_isolation.py.)"""

from __future__ import annotations

import datetime as dt
import re

import pytest
from django.core import mail
from django.test import Client
from django.utils import timezone
from rest_framework.test import APIClient

from accounts.models import ApiToken, Invite, User
from accounts.services import api_token_create
from tests.api_fixtures import token_client
from tests.factories import UserFactory

pytestmark = pytest.mark.django_db

LINK = re.compile(r"http://testserver(/accounts/invite/[^/\s]+/)")


def _invite(api: APIClient, email: str = "colleague@example.com", role: str = "viewer") -> str:
    """The path of the link the invitation's e-mail carries."""
    mail.outbox.clear()
    response = api.post("/api/v1/invites/", {"email": email, "role": role}, format="json")
    assert response.status_code == 201, response.content
    assert response.json()["role"] == role and response.json()["open"] is True
    (sent,) = mail.outbox
    assert sent.to == [email] and "Customer A" in sent.subject
    found = LINK.search(sent.body)
    assert found is not None, sent.body
    return found[1]


def _accept(link: str, username: str = "colleague") -> Client:
    browser = Client()
    response = browser.post(link, {"username": username, "password": "a-long-pass-phrase-9"})
    assert response.status_code == 302, response.content[:500]
    return browser


def test_an_invitation_makes_a_member_with_its_role(api_a, customer_a) -> None:
    link = _invite(api_a, role="developer")
    page = Client().get(link)
    assert page.status_code == 200 and b"Customer A" in page.content
    browser = _accept(link)
    member = User.objects.get(username="colleague")
    assert (member.customer, member.role, member.email) == (
        customer_a,
        "developer",
        "colleague@example.com",
    )
    assert browser.get("/").status_code == 200  # logged in at once
    listed = api_a.get("/api/v1/members/").json()["results"]
    assert {(m["username"], m["role"]) for m in listed} == {
        ("customer-a", "owner"),
        ("colleague", "developer"),
    }
    assert api_a.get("/api/v1/invites/").json()["count"] == 0  # used: no longer open


def test_an_invitation_works_once(api_a) -> None:
    link = _invite(api_a)
    _accept(link)
    again = Client().post(link, {"username": "second", "password": "a-long-pass-phrase-9"})
    assert again.status_code == 410 and b"used already" in again.content
    assert not User.objects.filter(username="second").exists()


def test_an_expired_invitation_is_refused(api_a) -> None:
    link = _invite(api_a)
    Invite.objects.update(expires=timezone.now() - dt.timedelta(seconds=1))
    for response in (Client().get(link), _post(link)):
        assert response.status_code == 410 and b"expired" in response.content
    assert not User.objects.filter(username="late").exists()


def _post(link: str):
    return Client().post(link, {"username": "late", "password": "a-long-pass-phrase-9"})


def test_a_withdrawn_or_forged_invitation_is_refused(api_a) -> None:
    link = _invite(api_a)
    (invite,) = api_a.get("/api/v1/invites/").json()["results"]
    assert api_a.delete(f"/api/v1/invites/{invite['id']}/").status_code == 204
    assert b"withdrawn" in Client().get(link).content
    forged = link.replace(link.split("/")[-2], link.split("/")[-2][:-2] + "xx")
    assert b"not an invitation" in Client().get(forged).content


def test_only_owners_invite_and_the_refusal_names_the_role(customer_a) -> None:
    developer = UserFactory(username="dev", customer=customer_a, role="developer")
    response = token_client(developer).post(
        "/api/v1/invites/", {"email": "x@example.com", "role": "viewer"}, format="json"
    )
    assert response.status_code == 403
    assert "needs the owner role" in response.json()["detail"]
    assert "you act as developer" in response.json()["detail"]
    assert not Invite.objects.exists() and not mail.outbox


def test_a_members_role_changes_and_the_last_owner_stays(api_a, user_a, customer_a) -> None:
    viewer = UserFactory(username="watcher", customer=customer_a, role="viewer")
    url = f"/api/v1/members/{viewer.pk}/"
    assert api_a.patch(url, {"role": "developer"}, format="json").json()["role"] == "developer"
    # The owner's token acts with the owner's role as it is now.
    own = f"/api/v1/members/{user_a.pk}/"
    refused = api_a.patch(own, {"role": "viewer"}, format="json")
    assert refused.status_code == 400 and "last owner" in refused.json()["detail"]
    api_a.patch(url, {"role": "owner"}, format="json")
    assert api_a.patch(own, {"role": "viewer"}, format="json").json()["role"] == "viewer"
    again = api_a.patch(url, {"role": "viewer"}, format="json")
    assert again.status_code == 403 and "you act as viewer" in again.json()["detail"]


def test_a_removed_members_tokens_die_with_them(api_a, customer_a) -> None:
    member = UserFactory(username="leaver", customer=customer_a, role="developer")
    member.set_password("password")
    member.save()
    _, key = api_token_create(user=member, name="laptop")
    theirs = APIClient()
    theirs.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    assert theirs.get("/api/v1/vvs/").status_code == 200
    assert api_a.delete(f"/api/v1/members/{member.pk}/").status_code == 204
    assert theirs.get("/api/v1/vvs/").status_code == 401
    assert not ApiToken.objects.filter(user=member).exists()
    member.refresh_from_db()
    assert not member.is_active
    login = Client().post("/accounts/login/", {"username": "leaver", "password": "password"})
    assert login.status_code == 200  # the form again: refused
    listed = [m["username"] for m in api_a.get("/api/v1/members/").json()["results"]]
    assert "leaver" not in listed


def test_a_token_acts_at_most_with_its_role(customer_a) -> None:
    developer = UserFactory(username="dev", customer=customer_a, role="developer")
    browser = APIClient()
    browser.force_login(developer)
    wider = browser.post("/api/v1/tokens/", {"name": "ci", "role": "owner"}, format="json")
    assert wider.status_code == 400 and "at most what you may" in wider.json()["detail"]
    made = browser.post("/api/v1/tokens/", {"name": "dash", "role": "viewer"}, format="json")
    assert made.status_code == 201 and made.json()["role"] == "viewer"
    dashboard = APIClient()
    dashboard.credentials(HTTP_AUTHORIZATION=f"Token {made.json()['key']}")
    assert dashboard.get("/api/v1/vvs/").status_code == 200
    submit = dashboard.post("/api/v1/vvs/", {"name": "x", "program": "var x;"}, format="json")
    assert submit.status_code == 403 and "needs the developer role" in submit.json()["detail"]
    # A member made a viewer: their tokens made without a role follow.
    plain = browser.post("/api/v1/tokens/", {"name": "plain"}, format="json").json()
    developer.role = "viewer"
    developer.save()
    follower = APIClient()
    follower.credentials(HTTP_AUTHORIZATION=f"Token {plain['key']}")
    refused = follower.post("/api/v1/vvs/", {"name": "x", "program": "var x;"}, format="json")
    assert refused.status_code == 403
