"""Hosts the site answers for come from the environment in production; Django's test host
("testserver") is the test environment's own, never a setting of the site."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

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


# Settings come from the environment through cpcc_site/env.py (read in settings.py) only. Not
# settings: V8's time zone, which the runtime pins for the process.
NOT_SETTINGS = {"cpcc_site/env.py", "vvm_worker/runtime/v8.py"}
READS = re.compile(r"os\.environ\.get\(|os\.getenv\(|os\.environ\[[^\]]+\](?!\s*=[^=])")


def test_no_module_reads_the_environment_but_the_settings() -> None:
    readers = sorted(
        str(path.relative_to(ROOT))
        for package in ("accounts", "fleet", "missions", "vvm_worker", "cpcc_site")
        for path in (ROOT / package).rglob("*.py")
        if str(path.relative_to(ROOT)) not in NOT_SETTINGS and READS.search(path.read_text())
    )
    assert readers == []


def _settings_read(code: str, tmp_path: Path, **env: str) -> Any:
    """What ``code`` prints (JSON) in a new interpreter with these environment variables."""
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env={
            **os.environ,
            "DJANGO_SETTINGS_MODULE": "cpcc_site.settings",
            "CPCC_VAR_DIR": str(tmp_path),
            **env,
        },
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)


def test_the_isolate_pool_and_the_database_pool_follow_the_environment(tmp_path: Path) -> None:
    code = (
        "import json, os, django; django.setup(); from django.conf import settings; "
        "from vvm_worker.runtime.pool import POOL; db = settings.DATABASES['default']; "
        "print(json.dumps([POOL.size, db['ENGINE'], db['CONN_MAX_AGE'], "
        "db['OPTIONS'].get('pool')]))"
    )

    def read(**env: str) -> Any:
        return _settings_read(code, tmp_path, **env)

    postgres = "postgres://cpcc@127.0.0.1:5432/cpcc"
    size, engine, max_age, pool = read(
        CPCC_ISOLATE_POOL="0", DATABASE_URL=postgres, CPCC_DB_POOL_SIZE="3"
    )
    assert (size, engine, max_age) == (0, "cpcc_site.postgresql", 0)
    assert pool["max_size"] == 3 and pool["timeout"] == 5.0
    size, engine, _, pool = read(DATABASE_URL=postgres, CPCC_DB_POOL_SIZE="0")
    assert (size, engine, pool) == (2, "django.db.backends.postgresql", None)
    # SQLite never pools.
    _, engine, _, pool = read(
        DATABASE_URL=f"sqlite:///{tmp_path}/db.sqlite3", CPCC_DB_POOL_SIZE="8"
    )
    assert (engine, pool) == ("django.db.backends.sqlite3", None)


def test_postgresql_prepares_repeated_statements_unless_told_not_to(tmp_path: Path) -> None:
    code = (
        "import json; from django.conf import settings; "
        "options = settings.DATABASES['default']['OPTIONS']; "
        "print(json.dumps([options.get('server_side_binding'), "
        "options.get('prepare_threshold')]))"
    )

    def read(**env: str) -> Any:
        return _settings_read(code, tmp_path, CPCC_ISOLATE_POOL="0", **env)

    postgres = "postgres://cpcc@127.0.0.1:5432/cpcc"
    assert read(DATABASE_URL=postgres) == [True, 5]
    assert read(DATABASE_URL=postgres, CPCC_DB_PREPARE_AFTER="2") == [True, 2]
    # PgBouncer before 1.21 in transaction mode: Django's default, nothing prepared.
    assert read(DATABASE_URL=postgres, CPCC_DB_PREPARE_AFTER="0") == [None, None]
    # With the pool too; SQLite has no such thing.
    assert read(DATABASE_URL=postgres, CPCC_DB_POOL_SIZE="3") == [True, 5]
    assert read(DATABASE_URL=f"sqlite:///{tmp_path}/db.sqlite3") == [None, None]
