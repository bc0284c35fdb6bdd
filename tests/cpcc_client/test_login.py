"""``cpcc login``: the command keeps a token made on the Account page and uses it; a revoked
token is refused, a wrong one is not kept, ``cpcc logout`` forgets it. Without a terminal it
reads the token from a pipe or CPCC_TOKEN, with no warning."""

from __future__ import annotations

import io
import json
import os
import re
import stat
import subprocess
import sys

import pytest
from django.test import Client

from accounts.models import ApiToken
from cpcc_client import cli
from vvm_worker.services import vv_submit

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

KEY = re.compile(r"cpcc_[0-9a-f]{64}")


@pytest.fixture
def config_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    return tmp_path / "config" / "cpcc"


def make_token(user, name: str) -> str:
    """A token made on the Account page, as its owner copies it."""
    browser = Client()
    browser.force_login(user)
    return KEY.search(browser.post("/accounts/tokens/", {"name": name}).content.decode())[0]


@pytest.fixture
def cpcc(live_server, config_dir, monkeypatch, capsys):
    """Run ``cpcc ARGS...`` with no CPCC_TOKEN; ``stdin`` is what the command reads."""
    monkeypatch.setenv("CPCC_URL", live_server.url)
    monkeypatch.delenv("CPCC_TOKEN", raising=False)

    def run(*args: str, stdin: str = "") -> tuple[int, str, str]:
        monkeypatch.setattr("sys.stdin", io.StringIO(stdin))
        code = cli.main(list(args))
        out, err = capsys.readouterr()
        return code, out, err

    return run


def test_cpcc_logs_in_with_a_token_made_on_the_account_page(
    cpcc, live_server, config_dir, user_a, vvm_factory
) -> None:
    browser = Client()
    browser.force_login(user_a)
    key = KEY.search(browser.post("/accounts/tokens/", {"name": "laptop"}).content.decode())[0]
    vv_submit(customer=user_a.customer, name="mine", program="VV.log(1);", vvm=vvm_factory())

    code, _, err = cpcc("list")
    assert code == 2
    assert f"run `cpcc login` with a token made on {live_server.url}/accounts/tokens/" in err

    code, out, err = cpcc("login", "--token-stdin", stdin=key + "\n")
    assert code == 0, err
    assert out.startswith(f"Logged in to {live_server.url} with the token 'laptop';")
    kept = config_dir / "credentials.json"
    assert json.loads(kept.read_text()) == {live_server.url: key}
    assert stat.S_IMODE(kept.stat().st_mode) == 0o600

    code, out, err = cpcc("list")
    assert code == 0 and "mine" in out, err

    token = ApiToken.objects.get(user=user_a)
    browser.post(f"/accounts/tokens/{token.pk}/revoke/")
    code, out, err = cpcc("list")
    assert code == 1 and out == "" and "401 Unauthorized: Invalid token." in err

    code, _, err = cpcc("login", "--token-stdin", stdin="cpcc_" + "0" * 64)
    assert code == 2 and "does not accept that token" in err
    assert json.loads(kept.read_text()) == {live_server.url: key}  # the old one, not the wrong one

    code, out, _ = cpcc("logout")
    assert code == 0 and out.startswith(f"Forgot the token for {live_server.url}.")
    assert json.loads(kept.read_text()) == {}


def test_a_token_piped_into_cpcc_login_is_kept_without_a_warning(
    live_server, config_dir, user_a
) -> None:
    key = make_token(user_a, "ci")
    env = {k: v for k, v in os.environ.items() if k != "CPCC_TOKEN"}
    env |= {"CPCC_URL": live_server.url, "XDG_CONFIG_HOME": str(config_dir.parent)}
    # A session of its own: no controlling terminal that getpass could open instead.
    done = subprocess.run(
        [sys.executable, "-m", "cpcc_client", "login"],
        input=key + "\n",
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        start_new_session=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"Logged in to {live_server.url} with the token 'ci';")
    assert "Warning" not in done.stderr and "API token:" not in done.stderr
    assert done.stderr == ""
    kept = json.loads((config_dir / "credentials.json").read_text())
    assert kept == {live_server.url: key}


def test_without_a_terminal_cpcc_login_takes_cpcc_token_when_nothing_is_piped(
    cpcc, live_server, config_dir, user_a, monkeypatch
) -> None:
    code, _, err = cpcc("login")
    assert code == 2 and "no token given" in err
    assert not (config_dir / "credentials.json").exists()

    key = make_token(user_a, "env")
    monkeypatch.setenv("CPCC_TOKEN", key)
    code, out, err = cpcc("login")
    assert code == 0, err
    assert out.startswith(f"Logged in to {live_server.url} with the token 'env';")
    assert "Warning" not in err
    assert json.loads((config_dir / "credentials.json").read_text()) == {live_server.url: key}
