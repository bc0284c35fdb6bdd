"""What each pytest-xdist worker needs of its own, set before Django reads its settings (this
plugin is loaded with ``-p tests.parallel``, ahead of pytest-django; see pyproject.toml).

- A database: pytest-django names the test database after the worker (``test_test_gw0``; the
  SQLite file has the worker's pid in its name already).
- A Redis: without ``REDIS_URL`` each worker starts an embedded server on a socket of its own
  (tests/conftest.py, ``broker_url``); with ``REDIS_URL`` (CI's second pass) worker ``gwN``
  uses database number ``base + N`` of that server, so no worker reads another's Celery queues,
  map feed or throttle counts.
- A var folder (``var/test-gwN``, or under ``CPCC_VAR_DIR``): SQLite test databases, static
  files, what the workers write. Media and ports are per test already (``tmp_path``, a free
  port from the kernel).

Run alone (``make test-serial``), nothing changes.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
REDIS_DATABASES = 16  # a Redis server's default number of databases


def worker_number() -> int | None:
    """N of the xdist worker ``gwN`` this process is, or None outside xdist."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    return int(worker[2:]) if re.fullmatch(r"gw\d+", worker) else None


def redis_url_of_worker(url: str, number: int) -> str:
    """``url`` with database ``base + number``: redis://host:port/0 -> redis://host:port/1."""
    match = re.fullmatch(r"(rediss?://[^/?#]+)(?:/(\d*))?(\?.*)?", url)
    if match is None:
        raise pytest.UsageError(
            f"REDIS_URL={url!r}: parallel tests need a redis:// URL to give each worker a database"
        )
    base = int(match.group(2) or 0)
    database = base + number
    if database >= REDIS_DATABASES:
        raise pytest.UsageError(
            f"REDIS_URL={url!r}: worker gw{number} would need Redis database {database}; "
            "use a lower database number or fewer workers"
        )
    return f"{match.group(1)}/{database}{match.group(3) or ''}"


@pytest.hookimpl(tryfirst=True)
def pytest_load_initial_conftests() -> None:
    number = worker_number()
    if number is None:
        return
    redis_url = os.environ.get("REDIS_URL")
    if redis_url and not redis_url.startswith("unix://"):
        os.environ["REDIS_URL"] = redis_url_of_worker(redis_url, number)
    var = Path(os.environ.get("CPCC_VAR_DIR") or ROOT / "var") / f"test-gw{number}"
    var.mkdir(parents=True, exist_ok=True)
    os.environ["CPCC_VAR_DIR"] = str(var)
