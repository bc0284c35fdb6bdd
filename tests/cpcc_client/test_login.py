"""``cpcc login``: the command keeps a token made on the Account page and uses it; a revoked
token is refused, a wrong one is not kept, ``cpcc logout`` forgets it."""

from __future__ import annotations

import io
import json
import re
import stat

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
