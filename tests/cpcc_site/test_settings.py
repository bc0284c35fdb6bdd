"""Hosts the site answers for come from the environment in production; Django's test host
("testserver") is the test environment's own, never a setting of the site."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.cpcc_site.test_security import ROOT, django_settings, production_env


def test_production_takes_its_hosts_from_the_environment_only(tmp_path: Path) -> None:
    listed = django_settings(production_env(tmp_path), "ALLOWED_HOSTS")
    assert listed["ALLOWED_HOSTS"] == ["cpcc.example.com"]
    unset = production_env(tmp_path)
    del unset["ALLOWED_HOSTS"]
    assert django_settings(unset, "ALLOWED_HOSTS")["ALLOWED_HOSTS"] == []
    development = {**unset, "DEBUG": "1"}
    hosts = django_settings(development, "ALLOWED_HOSTS")["ALLOWED_HOSTS"]
    assert hosts == ["localhost", "127.0.0.1", "[::1]"]


def test_a_production_server_refuses_the_test_clients_host(tmp_path: Path) -> None:
    """Django's test client says ``Host: testserver``: a production server answers it only if
    its ALLOWED_HOSTS lists it, listed or left unset."""
    code = (
        "import django; django.setup(); from django.test import Client; "
        "print(Client(raise_request_exception=False).get('/api/v1/vvs/').status_code)"
    )
    env = {
        **production_env(tmp_path),
        "CPCC_HTTPS": "0",
        "DJANGO_SETTINGS_MODULE": "cpcc_site.settings",
    }
    for hosts in ("cpcc.example.com", None):
        if hosts is None:
            del env["ALLOWED_HOSTS"]
        out = subprocess.run(
            [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True
        )
        assert out.returncode == 0, out.stderr
        assert out.stdout.split()[-1] == "400", hosts  # DisallowedHost
    env["ALLOWED_HOSTS"] = "testserver"  # what tests of a production setup would list
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert out.stdout.split()[-1] == "401"  # answered: the API asks for credentials
