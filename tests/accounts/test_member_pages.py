"""The Members page and roles on the pages (issue 57): every member reads who is in and who is
invited; an owner invites by e-mail (a signed link, used once, that expires), changes roles and
removes members (their tokens die with them). A viewer reads every page but changes nothing:
each change answers 403 saying the role it needs, before anything is looked up (a missing VV
and another customer's answer alike), and the pages offer no button a viewer cannot use; their
own password, tokens and e-mail choice stay theirs. Another customer's member, invitation or VV
is 404 to whoever may ask."""

from __future__ import annotations

import datetime as dt
import html
import re
import uuid

import pytest
from django.contrib.auth.models import Permission
from django.test import Client
from django.urls import reverse
from django.utils import timezone
from rest_framework.test import APIClient

from accounts.models import ApiToken, Invite, User, Webhook
from accounts.roles import DEVELOPER, OWNER, VIEWER
from accounts.services import api_token_create, invite_create, webhook_create
from missions.models import Message, VirtualVehicle, VVStatus
from tests.factories import UserFactory
from vvm_worker.services import vv_submit

pytestmark = pytest.mark.django_db

PASSWORD = "secret-pass-123"  # tests/factories.py's UserFactory
LINK = re.compile(r"https?://\S+/accounts/invite/[^/\s]+/")
MISSING_VV = uuid.UUID(int=1)


def logged_in(user) -> Client:
    client = Client()
    client.force_login(user)
    return client


def text(response) -> str:
    return html.unescape(response.content.decode())


def can_log_in(username: str, password: str) -> bool:
    """Whether the login form lets them in (it answers a refusal with the form again)."""
    answer = Client().post("/accounts/login/", {"username": username, "password": password})
    return answer.status_code == 302


def api_with(key: str) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    return client


@pytest.fixture
def developer(customer_a):
    return UserFactory(username="dev-a", customer=customer_a, role=DEVELOPER, email="dev@a.example")


@pytest.fixture
def viewer(customer_a):
    return UserFactory(
        username="viewer-a", customer=customer_a, role=VIEWER, email="viewer@a.example"
    )


@pytest.fixture
def invite_b(user_b):
    return invite_create(
        customer=user_b.customer,
        email="someone@b.example",
        role=VIEWER,
        invited_by=user_b,
        link=lambda signed: f"http://testserver/accounts/invite/{signed}/",
    )


def invite_by_page(client: Client, email: str, role: str, mailoutbox) -> str:
    """The owner's invitation through the page's form; the link its e-mail carries."""
    sent = len(mailoutbox)
    answer = client.post(reverse("account-members"), {"email": email, "role": role})
    assert answer.status_code == 302 and answer["Location"] == reverse("account-members")
    assert len(mailoutbox) == sent + 1
    mail = mailoutbox[-1]
    assert mail.to == [email]
    (link,) = LINK.findall(mail.body)
    return link.removeprefix("http://testserver")


# --- the Members page -----------------------------------------------------------------------


def test_every_member_reads_the_members_and_invitations_only_an_owner_changes_them(
    user_a, developer, viewer, user_b, invite_b, mailoutbox
) -> None:
    invite_by_page(logged_in(user_a), "new@a.example", DEVELOPER, mailoutbox)
    for member in (user_a, developer, viewer):
        answer = logged_in(member).get(reverse("account-members"))
        assert answer.status_code == 200, member
        page = text(answer)
        for name in ("customer-a", "dev-a", "viewer-a", "dev@a.example", "new@a.example"):
            assert name in page, (member, name)
        assert f"you are {member.role}" in page
        assert "customer-b" not in page and "someone@b.example" not in page
        owner_only = (
            'id="invite-form"',
            f'action="/accounts/members/{viewer.pk}/role/"',
            f'action="/accounts/members/{viewer.pk}/remove/"',
            "/withdraw/",
        )
        for marker in owner_only:
            assert (marker in page) is (member == user_a), (member, marker)
    tabs = text(logged_in(viewer).get(reverse("account-tokens")))
    assert '<a href="/accounts/members/">Members</a>' in tabs


def test_staff_have_no_members_to_manage(staff, user_a, developer) -> None:
    page = text(logged_in(staff).get(reverse("account-members")))
    assert "Members belong to a customer" in page and "dev-a" not in page
    browser = logged_in(staff)
    refused = browser.post(reverse("account-members"), {"email": "x@y.example", "role": VIEWER})
    assert refused.status_code == 403 and "Members belong to a customer" in text(refused)
    answer = browser.post(reverse("account-member-role", args=[developer.pk]), {"role": OWNER})
    assert answer.status_code == 404
    developer.refresh_from_db()
    assert developer.role == DEVELOPER


def test_only_an_owner_invites_changes_roles_removes_and_withdraws(
    user_a, developer, viewer, mailoutbox
) -> None:
    invite = invite_create(
        customer=user_a.customer,
        email="waiting@a.example",
        role=VIEWER,
        invited_by=user_a,
        link=lambda signed: signed,
    )
    mailoutbox.clear()
    for member in (developer, viewer):
        browser = logged_in(member)
        posts = {
            reverse("account-members"): {"email": "x@a.example", "role": OWNER},
            reverse("account-member-role", args=[viewer.pk]): {"role": OWNER},
            reverse("account-member-remove", args=[user_a.pk]): {},
            reverse("account-invite-withdraw", args=[invite.pk]): {},
            # A member that does not exist answers the same: nothing is looked up.
            reverse("account-member-remove", args=[999_999]): {},
        }
        for url, data in posts.items():
            refused = browser.post(url, data)
            assert refused.status_code == 403, (member, url)
            assert f"needs the owner role or higher; you act as {member.role}" in text(refused), url
    assert not mailoutbox
    assert Invite.objects.filter(pk=invite.pk).exists()
    assert {
        (u.username, u.role, u.is_active) for u in User.objects.filter(customer=user_a.customer)
    } == {
        ("customer-a", OWNER, True),
        ("dev-a", DEVELOPER, True),
        ("viewer-a", VIEWER, True),
    }


def test_another_customers_member_or_invitation_is_not_found(
    user_a, user_b, invite_b, developer
) -> None:
    browser = logged_in(user_a)
    for url, data in (
        (reverse("account-member-role", args=[user_b.pk]), {"role": VIEWER}),
        (reverse("account-member-remove", args=[user_b.pk]), {}),
        (reverse("account-invite-withdraw", args=[invite_b.pk]), {}),
        (reverse("account-member-remove", args=[999_999]), {}),
        (reverse("account-invite-withdraw", args=[999_999]), {}),
    ):
        assert browser.post(url, data).status_code == 404, url
    user_b.refresh_from_db()
    assert (user_b.role, user_b.is_active) == (OWNER, True)
    assert Invite.objects.filter(pk=invite_b.pk).exists()
    # B's owner cannot reach A's member either.
    answer = logged_in(user_b).post(
        reverse("account-member-role", args=[developer.pk]), {"role": VIEWER}
    )
    assert answer.status_code == 404


# --- invitations ------------------------------------------------------------------------------


def test_an_invitation_is_mailed_accepted_once_and_logs_the_new_member_in(
    user_a, mailoutbox, vv_a
) -> None:
    link = invite_by_page(logged_in(user_a), "colleague@a.example", VIEWER, mailoutbox)
    mail = mailoutbox[-1]
    assert "customer-a invites you to Customer A" in mail.subject
    assert "as viewer" in mail.body
    assert "colleague@a.example" in text(logged_in(user_a).get(reverse("account-members")))

    invitee = Client()
    page = invitee.get(link)
    assert page.status_code == 200
    assert "invites colleague@a.example to join" in text(page) and "Customer A" in text(page)
    accepted = invitee.post(link, {"username": "colleague", "password": "a-long-passphrase"})
    assert accepted.status_code == 302 and accepted["Location"] == reverse("home")
    member = User.objects.get(username="colleague")
    assert (member.customer_id, member.role, member.email) == (
        user_a.customer_id,
        VIEWER,
        "colleague@a.example",
    )
    assert invitee.session["_auth_user_id"] == str(member.pk)
    home = text(invitee.get(reverse("home")))
    assert "Welcome to Customer A: you are a viewer." in home and "Alpha VV" in home
    assert can_log_in("colleague", "a-long-passphrase")

    members = text(logged_in(user_a).get(reverse("account-members")))
    assert "colleague" in members and "No invitation waits." in members

    again = Client().post(link, {"username": "other", "password": "a-long-passphrase"})
    assert again.status_code == 410 and "used already" in text(again)
    assert Client().get(link).status_code == 410
    assert not User.objects.filter(username="other").exists()


def test_an_expired_invitation_is_refused(user_a, mailoutbox) -> None:
    link = invite_by_page(logged_in(user_a), "late@a.example", DEVELOPER, mailoutbox)
    Invite.objects.update(expires=timezone.now() - dt.timedelta(seconds=1))
    for answer in (
        Client().get(link),
        Client().post(link, {"username": "late", "password": "a-long-passphrase"}),
    ):
        assert answer.status_code == 410 and "This invitation expired" in text(answer)
    assert not User.objects.filter(username="late").exists()
    members = text(logged_in(user_a).get(reverse("account-members")))
    assert "late@a.example" in members and "expired" in members


def test_a_tampered_or_withdrawn_link_is_refused(user_a, mailoutbox) -> None:
    owner = logged_in(user_a)
    link = invite_by_page(owner, "twice@a.example", DEVELOPER, mailoutbox)
    signed = link.rstrip("/").rsplit("/", 1)[1]
    tampered = reverse(
        "account-invite", args=[signed[:-2] + ("AA" if signed[-2:] != "AA" else "BB")]
    )
    answer = Client().post(tampered, {"username": "sneaky", "password": "a-long-passphrase"})
    assert answer.status_code == 410 and "not an invitation" in text(answer)

    invite = Invite.objects.get()
    withdrawn = owner.post(reverse("account-invite-withdraw", args=[invite.pk]), follow=True)
    assert "The invitation to twice@a.example is withdrawn" in text(withdrawn)
    answer = Client().get(link)
    assert answer.status_code == 410 and "withdrawn" in text(answer)
    assert not User.objects.filter(username="sneaky").exists()


def test_a_bad_invitation_is_refused_on_the_page(user_a, developer, mailoutbox) -> None:
    browser = logged_in(user_a)
    for data, problem in (
        ({"email": "not an address", "role": VIEWER}, "is not an e-mail address"),
        ({"email": "dev@a.example", "role": VIEWER}, "dev@a.example is a member already"),
        ({"email": "x@a.example", "role": "admin"}, "Select a valid choice"),
    ):
        answer = browser.post(reverse("account-members"), data)
        assert answer.status_code == 400 and problem in text(answer), data
    assert not mailoutbox and not Invite.objects.exists()


def test_the_invitation_page_says_what_is_wrong_with_the_new_account(
    user_a, developer, mailoutbox
) -> None:
    link = invite_by_page(logged_in(user_a), "n@a.example", VIEWER, mailoutbox)
    taken = Client().post(link, {"username": "dev-a", "password": "a-long-passphrase"})
    assert taken.status_code == 200 and "is taken" in text(taken)
    short = Client().post(link, {"username": "newbie", "password": "short"})
    assert short.status_code == 200 and "too short" in text(short)
    assert Invite.objects.get().accepted is None


# --- roles and removal ------------------------------------------------------------------------


def test_an_owner_changes_a_role_and_the_last_owner_stays_owner(user_a, viewer) -> None:
    browser = logged_in(user_a)
    changed = browser.post(
        reverse("account-member-role", args=[viewer.pk]), {"role": DEVELOPER}, follow=True
    )
    assert "viewer-a is now developer." in text(changed)
    viewer.refresh_from_db()
    assert viewer.role == DEVELOPER

    kept = browser.post(
        reverse("account-member-role", args=[user_a.pk]), {"role": VIEWER}, follow=True
    )
    assert "The last owner stays owner" in text(kept)
    user_a.refresh_from_db()
    assert user_a.role == OWNER

    bad = browser.post(
        reverse("account-member-role", args=[viewer.pk]), {"role": "root"}, follow=True
    )
    assert "Choose a role" in text(bad)
    viewer.refresh_from_db()
    assert viewer.role == DEVELOPER


def test_a_removed_member_cannot_log_in_and_their_token_is_refused(
    user_a, developer, settings
) -> None:
    settings.CPCC_TOKEN_CACHE_S = 0.0
    _, key = api_token_create(user=developer, name="laptop")
    assert api_with(key).get("/api/v1/vvs/").status_code == 200
    session = logged_in(developer)
    assert session.get(reverse("home")).status_code == 200

    removed = logged_in(user_a).post(
        reverse("account-member-remove", args=[developer.pk]), follow=True
    )
    page = text(removed)
    assert "dev-a is removed" in page
    assert f'data-member-id="{developer.pk}"' not in page
    assert api_with(key).get("/api/v1/vvs/").status_code == 401
    assert not ApiToken.objects.filter(user=developer).exists()
    assert not can_log_in("dev-a", PASSWORD)
    answer = session.get(reverse("home"))
    assert answer.status_code == 302 and answer["Location"].startswith("/accounts/login/")


def test_the_last_owner_cannot_be_removed(user_a) -> None:
    answer = logged_in(user_a).post(reverse("account-member-remove", args=[user_a.pk]), follow=True)
    assert "The last owner cannot be removed" in text(answer)
    user_a.refresh_from_db()
    assert user_a.is_active


# --- a viewer's own things: tokens (with a role), e-mails, password ---------------------------


def test_a_token_is_made_with_a_narrower_role_and_shows_what_it_may_do(
    user_a, developer, settings
) -> None:
    settings.CPCC_TOKEN_CACHE_S = 0.0
    owner = logged_in(user_a)
    page = text(owner.get(reverse("account-tokens")))
    options = re.findall(r'<option value="([^"]*)"', page)
    assert options == ["", DEVELOPER, VIEWER]
    owner.post(reverse("account-tokens"), {"name": "dashboard", "role": VIEWER})
    owner.post(reverse("account-tokens"), {"name": "laptop", "role": ""})
    tokens = {t.name: t.role for t in ApiToken.objects.filter(user=user_a)}
    assert tokens == {"dashboard": VIEWER, "laptop": ""}
    page = text(owner.get(reverse("account-tokens")))
    dashboard = re.search(
        r'<tr data-token-id="\d+">\s*<td class="name">dashboard.*?</tr>', page, re.S
    )[0]
    laptop = re.search(r'<tr data-token-id="\d+">\s*<td class="name">laptop.*?</tr>', page, re.S)[0]
    assert ">viewer<" in dashboard and "as it changes" not in dashboard
    assert ">owner<" in laptop and "yours, as it changes" in laptop

    # A developer is not offered owner, and cannot send it.
    browser = logged_in(developer)
    assert re.findall(r'<option value="([^"]*)"', text(browser.get(reverse("account-tokens")))) == [
        "",
        VIEWER,
    ]
    refused = browser.post(reverse("account-tokens"), {"name": "wide", "role": OWNER})
    assert refused.status_code == 400 and "Select a valid choice" in text(refused)
    assert not ApiToken.objects.filter(user=developer).exists()


def test_a_viewer_keeps_their_own_tokens_email_and_password(viewer) -> None:
    browser = logged_in(viewer)
    page = text(browser.get(reverse("account-tokens")))
    assert 'name="role"' not in page  # nothing narrower to choose
    made = browser.post(reverse("account-tokens"), {"name": "dashboard"})
    assert made.status_code == 200 and "Your new token" in text(made)
    assert ApiToken.objects.get(user=viewer).role == ""

    saved = browser.post(
        reverse("account-notifications"),
        {"email": "me@a.example", "email_events": ["vv.failed"]},
    )
    assert saved.status_code == 302
    viewer.refresh_from_db()
    assert (viewer.email, viewer.email_events) == ("me@a.example", ["vv.failed"])

    changed = browser.post(
        reverse("password_change"),
        {
            "old_password": PASSWORD,
            "new_password1": "another-long-pass",
            "new_password2": "another-long-pass",
        },
    )
    assert changed.status_code == 302
    assert can_log_in("viewer-a", "another-long-pass")


def test_a_viewer_reads_the_webhooks_but_neither_adds_nor_removes_one(
    user_a, viewer, developer, settings
) -> None:
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True
    webhook = webhook_create(
        customer=user_a.customer,
        url="http://127.0.0.1:9/hook",
        events=["vv.failed"],
        allow_private=True,
    )
    browser = logged_in(viewer)
    page = text(browser.get(reverse("account-notifications")))
    assert "http://127.0.0.1:9/hook" in page
    assert 'action="/accounts/webhooks/new/"' not in page and "/remove/" not in page
    assert "a developer or an owner adds and removes them" in page
    for url in (
        reverse("account-webhook-new"),
        reverse("account-webhook-remove", args=[webhook.pk]),
        reverse("account-webhook-remove", args=[999_999]),
    ):
        refused = browser.post(url, {"url": "http://127.0.0.1:9/other", "events": ["vv.failed"]})
        assert refused.status_code == 403, url
        assert "needs the developer role or higher; you act as viewer" in text(refused)
    assert list(Webhook.objects.values_list("url", flat=True)) == ["http://127.0.0.1:9/hook"]

    dev = logged_in(developer)
    assert 'action="/accounts/webhooks/new/"' in text(dev.get(reverse("account-notifications")))
    made = dev.post(
        reverse("account-webhook-new"),
        {"url": "http://127.0.0.1:9/other", "events": ["vv.finished"]},
    )
    assert made.status_code == 200
    assert dev.post(reverse("account-webhook-remove", args=[webhook.pk])).status_code == 302
    assert list(Webhook.objects.values_list("url", flat=True)) == ["http://127.0.0.1:9/other"]


# --- roles on the VV pages --------------------------------------------------------------------


@pytest.fixture
def page_vvm(monkeypatch, vvm_factory):
    """The VVM the pages' actions use: a recording dispatcher instead of Celery."""
    import missions.views

    vvm = vvm_factory()
    monkeypatch.setattr(missions.views, "platform_vvm", lambda: vvm)
    return vvm


@pytest.fixture
def vv_a(customer_a, ground_station, vvm_factory):
    return vv_submit(customer=customer_a, name="Alpha VV", program="var a = 1;", vvm=vvm_factory())


@pytest.fixture
def queued_a(customer_a, vvm_factory):
    """Customer A's VV waiting in the queue (no ground station to take it)."""
    return vv_submit(customer=customer_a, name="Draft", program="var d = 1;", vvm=vvm_factory())


@pytest.fixture
def vv_b(customer_b, ground_station, vvm_factory):
    return vv_submit(customer=customer_b, name="Bravo VV", program="var b = 1;", vvm=vvm_factory())


def change_requests(vv_id) -> list[tuple[str, str, dict]]:
    """Every change a VV's pages offer, for the VV ``vv_id``."""
    program = {"name": "Changed", "program": "var c = 2;", "copies": 1}
    return [
        ("get", reverse("vv-new"), {}),
        ("get", f"{reverse('vv-new')}?from={vv_id}", {}),
        ("post", reverse("vv-new"), program),
        ("post", reverse("vv-check"), {"program": "var c = 2;"}),
        ("get", reverse("vv-edit", args=[vv_id]), {}),
        ("post", reverse("vv-edit", args=[vv_id]), program),
        ("post", reverse("vv-cancel", args=[vv_id]), {}),
        ("post", reverse("vv-restart", args=[vv_id]), {}),
        ("post", reverse("vv-detail", args=[vv_id]), {"value": '"hello"'}),
    ]


def test_a_viewer_is_refused_every_change_the_same_for_any_vv(
    viewer, queued_a, vv_a, vv_b, page_vvm
) -> None:
    browser = logged_in(viewer)
    before = sorted(VirtualVehicle.objects.values_list("id", "name", "status", "program"))
    for vv_id in (queued_a.pk, vv_a.pk, vv_b.pk, MISSING_VV):
        for method, url, data in change_requests(vv_id):
            answer = getattr(browser, method)(url, data)
            assert answer.status_code == 403, (method, url)
            assert "needs the developer role or higher; you act as viewer" in text(answer), url
    assert sorted(VirtualVehicle.objects.values_list("id", "name", "status", "program")) == before
    assert not Message.objects.exists()
    assert page_vvm.dispatcher.slots == []


def test_a_viewer_reads_the_vv_pages_without_a_button_to_change_anything(
    viewer, queued_a, vv_a, page_vvm
) -> None:
    VirtualVehicle.objects.filter(pk=vv_a.pk).update(status=VVStatus.FINISHED)
    browser = logged_in(viewer)
    dashboard = text(browser.get(reverse("home")))
    assert "Alpha VV" in dashboard and "Draft" in dashboard
    for vv in (queued_a, vv_a):
        page = text(browser.get(reverse("vv-detail", args=[vv.pk])))
        assert vv.name in page
        for pages in (page, dashboard):
            for action in ("cancel", "restart", "edit"):
                assert f"/vvs/{vv.pk}/{action}/" not in pages, (vv.name, action)
        assert "Copy to a new VV" not in page and 'name="value"' not in page
        assert 'href="/vvs/new/' not in page
    assert 'href="/vvs/new/' not in dashboard


def test_a_developer_changes_their_customers_vvs_not_another_customers(
    developer, queued_a, vv_b, page_vvm
) -> None:
    browser = logged_in(developer)
    page = text(browser.get(reverse("vv-detail", args=[queued_a.pk])))
    for action in ("cancel", "edit"):
        assert f"/vvs/{queued_a.pk}/{action}/" in page
    assert "Copy to a new VV" in page and 'name="value"' in page
    assert 'href="/vvs/new/"' in page  # the navigation's New VV
    assert browser.get(reverse("vv-new")).status_code == 200
    assert browser.get(reverse("vv-edit", args=[queued_a.pk])).status_code == 200
    checked = browser.post(reverse("vv-check"), {"program": "var c = 2;"})
    assert checked.status_code == 200 and checked.json() == {"ok": True}
    for url in (reverse("vv-cancel", args=[vv_b.pk]), reverse("vv-edit", args=[vv_b.pk])):
        assert browser.post(url, {"name": "x", "program": "var x;"}).status_code == 404, url
    assert browser.post(reverse("vv-cancel", args=[MISSING_VV])).status_code == 404
    assert browser.post(reverse("vv-cancel", args=[queued_a.pk])).status_code == 302
    queued_a.refresh_from_db()
    assert queued_a.status == VVStatus.CANCELLED
    vv_b.refresh_from_db()
    assert vv_b.status != VVStatus.CANCELLED


def test_staff_change_a_customers_vv_on_the_pages_only_with_the_permission(
    queued_a, page_vvm
) -> None:
    def perm(codename: str) -> Permission:
        return Permission.objects.get(codename=codename, content_type__app_label="missions")

    support = UserFactory(username="support", is_staff=True)
    support.user_permissions.add(perm("view_virtualvehicle"))  # reads every VV, changes none
    browser = logged_in(support)
    page = text(browser.get(reverse("vv-detail", args=[queued_a.pk])))
    assert "Draft" in page and f"/vvs/{queued_a.pk}/cancel/" not in page
    for url in (reverse("vv-cancel", args=[queued_a.pk]), reverse("vv-cancel", args=[MISSING_VV])):
        refused = browser.post(url)
        assert refused.status_code == 403, url
        assert "missions.change_virtualvehicle" in text(refused)
    queued_a.refresh_from_db()
    assert queued_a.status == VVStatus.QUEUED

    support.user_permissions.add(perm("change_virtualvehicle"))
    browser = logged_in(User.objects.get(pk=support.pk))  # permissions are cached per object
    assert f"/vvs/{queued_a.pk}/cancel/" in text(
        browser.get(reverse("vv-detail", args=[queued_a.pk]))
    )
    assert browser.post(reverse("vv-cancel", args=[MISSING_VV])).status_code == 404
    assert browser.post(reverse("vv-cancel", args=[queued_a.pk])).status_code == 302
    queued_a.refresh_from_db()
    assert queued_a.status == VVStatus.CANCELLED
