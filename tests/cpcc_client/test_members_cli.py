"""``cpcc members`` end to end against a live server, run in-process: an owner lists, invites,
changes roles and removes; a viewer (or a read-only token) is refused with the platform's
sentence naming the role it needs; another customer's members are not there."""

from __future__ import annotations

import json

import pytest
from django.core import mail
from rest_framework.authtoken.models import Token

from accounts.models import Invite, User
from accounts.services import api_token_create
from cpcc_client import cli
from tests.factories import UserFactory

# The live server sees the test's data only when it is committed.
pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

OWNERS_ONLY = (
    "cpcc: 403 Forbidden: Doing {action} needs the owner role or higher; you act as viewer. "
    "Ask an owner of your customer if you need to."
)


@pytest.fixture
def team(customer_a, user_a, user_b):
    """Customer A: its owner (customer-a), a developer with an address, a viewer; customer B's
    own user beside them."""
    UserFactory(username="dev", customer=customer_a, role="developer", email="dev@example.org")
    UserFactory(username="vera", customer=customer_a, role="viewer")
    return customer_a


@pytest.fixture
def cpcc(live_server, monkeypatch, capsys):
    """``cpcc(user or token key, ARGS...)``: run ``cpcc ARGS...`` with that user's token (or
    that key); returns (exit code, stdout, stderr)."""
    monkeypatch.setenv("CPCC_URL", live_server.url)

    def run(who: User | str, *args: str) -> tuple[int, str, str]:
        key = who if isinstance(who, str) else Token.objects.get_or_create(user=who)[0].key
        monkeypatch.setenv("CPCC_TOKEN", key)
        code = cli.main(list(args))
        out, err = capsys.readouterr()
        return code, out, err

    return run


def test_members_lists_user_name_e_mail_and_role_of_your_customer_only(cpcc, team, user_a) -> None:
    code, out, err = cpcc(user_a, "members")
    assert code == 0, err
    assert out.splitlines() == [
        "USER        E-MAIL           ROLE",
        "customer-a  -                owner",
        "dev         dev@example.org  developer",
        "vera        -                viewer",
    ]
    code, out, _ = cpcc(user_a, "members", "--json")
    assert [(m["username"], m["role"]) for m in json.loads(out)] == [
        ("customer-a", "owner"),
        ("dev", "developer"),
        ("vera", "viewer"),
    ]
    # A viewer reads them too.
    code, out, _ = cpcc(User.objects.get(username="vera"), "members")
    assert code == 0 and len(out.splitlines()) == 4


def test_an_owner_invites_changes_a_role_and_removes_a_member(cpcc, team, user_a) -> None:
    code, out, err = cpcc(user_a, "members", "invite", "new@example.org", "--role", "developer")
    assert code == 0, err
    invite = Invite.objects.get()
    assert (invite.customer, invite.email, invite.role) == (team, "new@example.org", "developer")
    assert out.startswith("Invited new@example.org as developer: the link in the e-mail works once")
    assert [m.to for m in mail.outbox] == [["new@example.org"]]

    code, out, err = cpcc(user_a, "members", "role", "vera", "developer")
    assert (code, out, err) == (0, "vera is now developer.\n", "")
    assert User.objects.get(username="vera").role == "developer"
    # A member named by their e-mail address.
    code, out, _ = cpcc(user_a, "members", "role", "DEV@example.org", "owner")
    assert (code, out) == (0, "dev is now owner.\n")

    vera = User.objects.get(username="vera")
    vera_key = Token.objects.get_or_create(user=vera)[0].key
    code, out, err = cpcc(user_a, "members", "remove", "vera")
    assert (code, err) == (0, "")
    assert out == (
        "Removed vera: they can no longer log in, and their API tokens no longer work.\n"
    )
    assert not User.objects.get(username="vera").is_active
    code, _, err = cpcc(vera_key, "members")  # their token died with them
    assert code == 1 and err.startswith("cpcc: 401 Unauthorized")
    assert "vera" not in cpcc(user_a, "members")[1]


def test_a_viewer_is_refused_with_the_role_it_needs_and_exit_1(cpcc, team) -> None:
    vera = User.objects.get(username="vera")
    code, out, err = cpcc(vera, "members", "invite", "new@example.org", "--role", "viewer")
    assert (code, out) == (1, "")
    assert err.strip() == OWNERS_ONLY.format(action="create of invitation")
    code, out, err = cpcc(vera, "members", "role", "dev", "viewer")
    assert (code, out) == (1, "")
    assert err.strip() == OWNERS_ONLY.format(action="partial update of member")
    code, out, err = cpcc(vera, "members", "remove", "dev")
    assert (code, out) == (1, "")
    assert err.strip() == OWNERS_ONLY.format(action="destroy of member")
    assert not Invite.objects.exists()
    assert User.objects.get(username="dev").role == "developer"
    assert User.objects.get(username="dev").is_active


def test_an_owners_read_only_token_is_refused_as_a_viewer(cpcc, team, user_a) -> None:
    _, key = api_token_create(user=user_a, name="dashboard", role="viewer")
    assert cpcc(key, "members")[0] == 0
    code, _, err = cpcc(key, "members", "remove", "vera")
    assert code == 1
    assert err.strip() == OWNERS_ONLY.format(action="destroy of member")
    assert User.objects.get(username="vera").is_active


def test_a_member_of_another_customer_or_nobody_is_not_found(cpcc, team, user_a) -> None:
    for name in ("customer-b", "nobody"):
        code, out, err = cpcc(user_a, "members", "remove", name)
        assert (code, out) == (1, "")
        assert err.strip() == (
            f"cpcc: no member {name!r} in your customer (its members: customer-a, dev, vera)"
        )
    assert User.objects.get(username="customer-b").is_active


def test_the_last_owner_stays_owner(cpcc, team, user_a) -> None:
    code, out, err = cpcc(user_a, "members", "role", "customer-a", "viewer")
    assert (code, out) == (1, "")
    assert err.startswith("cpcc: 400 Bad Request")
    assert "The last owner stays owner: make another member owner first." in err
    assert User.objects.get(username="customer-a").role == "owner"


def test_a_role_that_is_none_is_a_usage_error(capsys) -> None:
    with pytest.raises(SystemExit) as usage:
        cli.main(["members", "invite", "new@example.org", "--role", "admin"])
    assert usage.value.code == 2
    assert "invalid choice: 'admin'" in capsys.readouterr().err
