"""Production settings from the environment, and the pages' Content Security Policy."""

from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest
from django.test import Client

from cpcc_site.security import tile_origin

ROOT = Path(__file__).resolve().parents[2]


def production_env(tmp_path: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DJANGO", "CPCC", "SECURE"))}
    env.update(
        DEBUG="0",
        SECRET_KEY=secrets.token_urlsafe(50),
        ALLOWED_HOSTS="cpcc.example.com",
        CPCC_VAR_DIR=str(tmp_path),
        **extra,
    )
    return env


def django_settings(env: dict[str, str], *names: str) -> dict[str, object]:
    """These settings as a new process with ``env`` reads them (the settings module alone:
    setting up the apps, a second more, changes no setting)."""
    code = (
        "import json; from django.conf import settings; "
        f"print(json.dumps({{n: getattr(settings, n, None) for n in {list(names)!r}}}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env={**env, "DJANGO_SETTINGS_MODULE": "cpcc_site.settings"},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)


def test_check_deploy_is_clean_with_production_variables(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "manage.py", "check", "--deploy", "--fail-level", "WARNING"],
        cwd=ROOT,
        env=production_env(tmp_path),
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "no issues" in out.stdout


def test_https_settings_come_from_the_environment(tmp_path: Path) -> None:
    names = ("SECURE_SSL_REDIRECT", "SESSION_COOKIE_SECURE", "CSRF_COOKIE_SECURE",
             "SECURE_HSTS_SECONDS", "SECURE_PROXY_SSL_HEADER", "CSRF_TRUSTED_ORIGINS")  # fmt: skip
    production = django_settings(production_env(tmp_path), *names)
    assert production["SECURE_SSL_REDIRECT"] is True
    assert production["SESSION_COOKIE_SECURE"] is production["CSRF_COOKIE_SECURE"] is True
    assert production["SECURE_HSTS_SECONDS"] == 31_536_000
    behind_proxy = django_settings(
        production_env(
            tmp_path,
            SECURE_PROXY_SSL_HEADER="HTTP_X_FORWARDED_PROTO,https",
            SECURE_SSL_REDIRECT="0",
            SECURE_HSTS_SECONDS="3600",
            CSRF_TRUSTED_ORIGINS="https://cpcc.example.com",
        ),
        *names,
    )
    assert behind_proxy["SECURE_PROXY_SSL_HEADER"] == ["HTTP_X_FORWARDED_PROTO", "https"]
    assert behind_proxy["SECURE_SSL_REDIRECT"] is False
    assert behind_proxy["SECURE_HSTS_SECONDS"] == 3600
    assert behind_proxy["CSRF_TRUSTED_ORIGINS"] == ["https://cpcc.example.com"]
    # Development (DEBUG on) keeps plain HTTP working.
    development = django_settings({**production_env(tmp_path), "DEBUG": "1"}, *names)
    assert development["SECURE_SSL_REDIRECT"] is False


def test_production_refuses_to_start_without_a_secret_key(tmp_path: Path) -> None:
    env = production_env(tmp_path)
    del env["SECRET_KEY"]
    out = subprocess.run(
        [sys.executable, "manage.py", "check"], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert out.returncode != 0
    assert "SECRET_KEY must be set" in out.stderr


@pytest.mark.django_db
def test_pages_allow_scripts_from_this_site_only(client: Client, django_user_model) -> None:
    staff = django_user_model.objects.create_superuser("ops", password="pw-12345678")
    client.force_login(staff)
    for path in ("/", "/map/", "/admin/", "/admin/fleet/vehicle/add/"):
        response = client.get(path)
        assert response.status_code == 200, path
        policy = response["Content-Security-Policy"]
        directives = dict(d.split(" ", 1) for d in policy.split("; "))
        assert directives["script-src"] == "'self'", path
        assert directives["object-src"] == "'none'"
        assert directives["frame-ancestors"] == "'none'"
        assert "ws://testserver" in directives["connect-src"]
    # Swagger UI starts itself with an inline script: that page alone may run one.
    docs = client.get("/api/docs/")
    assert "script-src 'self' 'unsafe-inline'" in docs["Content-Security-Policy"]
    # JSON carries no policy: it is not a page.
    assert "Content-Security-Policy" not in client.get("/api/v1/vvs/")


def test_map_tiles_are_allowed_by_origin() -> None:
    assert tile_origin("") == ""
    assert tile_origin("https://tile.example.org/{z}/{x}/{y}.png") == "https://tile.example.org"
    assert tile_origin("https://{s}.tile.example.org/{z}/{x}/{y}.png") == (
        "https://*.tile.example.org"
    )
