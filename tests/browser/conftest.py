"""Browser tests: Playwright drives Debian's Chromium (/usr/bin/chromium) against the real
system, each part a process of its own as in ``make demo``: the ASGI server (daphne: pages,
static files and the live map's socket) and a worker per ground station and per RV, all on the
test database and the test run's Redis.

pytest-django's ``live_server`` is WSGI only (no WebSocket), hence daphne in a subprocess. What
a test creates must be committed for the server and the workers to see it: the tests are
transactional (``django_db(transaction=True)``).

Without /usr/bin/chromium every test here is skipped with one reason (``make test`` says so
too); nothing is ever downloaded (no ``playwright install``).
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import dj_database_url
import pytest
from django.conf import settings
from django.contrib.auth.hashers import PBKDF2PasswordHasher
from django.db import connection, connections
from playwright.sync_api import (
    Browser,
    BrowserContext,
    BrowserType,
    Page,
    Playwright,
    expect,
    sync_playwright,
)

from accounts.models import Customer
from fleet.models import GroundStation, Vehicle
from missions.events import EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH
from tests.browser.pages import FIELD
from tests.browser.traffic import Traffic
from tests.factories import CustomerFactory, GroundStationFactory, UserFactory, VehicleFactory
from tests.live import ROOT, Workers, database_url
from tests.polling import wait_until

CHROMIUM = Path("/usr/bin/chromium")
SKIPPED = "browser tests: skipped (no /usr/bin/chromium; apt-get install chromium)"
HERE = Path(__file__).resolve().parent
ASGI_APP = "cpcc_site.asgi:application"
# An access-log line of daphne's for a request that went well.
FINE = re.compile(r'" [23]\d\d [-\d]+$|"WS(CONNECTING|CONNECT|DISCONNECT) ')

# The machine has no display, no GPU and no internet: nothing in the background may phone home.
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

# How long an expectation waits for the page to get there (Playwright's default: 5 s). The
# suite runs on two busy cores beside other tests' servers and workers (make test); a heavy
# page (the API's docs render the whole schema in the browser) can take longer than 5 s there.
expect.set_options(timeout=15_000)

# Simulated vehicles fly this many times faster than real time: fast enough for a short test,
# slow enough that the map shows a vehicle between two points (0 would jump from stop to stop).
SIM_SPEED = 6


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every test here is marked ``browser``, and skipped (with one reason) without Chromium."""
    skip = None if CHROMIUM.exists() else pytest.mark.skip(reason=SKIPPED)
    for item in items:
        if HERE in Path(item.path).parents:
            item.add_marker(pytest.mark.browser)
            if skip is not None:
                item.add_marker(skip)


# --- the browser -------------------------------------------------------------------------


@pytest.fixture(scope="session")
def browser_type_launch_args() -> dict:
    return {"executable_path": str(CHROMIUM), "headless": True, "args": CHROMIUM_ARGS}


@pytest.fixture(scope="package")
def base_url(asgi_server: Server) -> str:
    """Pages open relative to the server: ``page.goto("/map/")``."""
    return asgi_server.url


# pytest-playwright keeps Playwright for the whole session, but its sync API leaves an asyncio
# loop running in the test thread, which the rest of the suite must not inherit (Django's ORM
# would refuse to work, pytest-asyncio could not start loops): here it lives as long as this
# folder's tests, and so do the fixtures built on it.


@pytest.fixture(scope="package")
def playwright() -> Iterator[Playwright]:
    # Django keeps a database connection per thread, and per asyncio context while a loop runs
    # in the thread: without this, the tests would get new connections without what
    # pytest-django prepared on the old ones (the serialized data that serialized_rollback
    # restores), left open when the test database is dropped.
    kept = {alias: connections[alias] for alias in connections}
    with sync_playwright() as pw:
        for alias, kept_connection in kept.items():
            connections[alias] = kept_connection
        yield pw
        for alias in kept:
            del connections[alias]  # only from the loop's storage: async tests start afresh


@pytest.fixture(scope="package")
def browser_type(playwright: Playwright, browser_name: str) -> BrowserType:
    return getattr(playwright, browser_name)


@pytest.fixture(scope="package")
def launch_browser(browser_type_launch_args: dict, browser_type: BrowserType):
    return lambda **kwargs: browser_type.launch(**{**browser_type_launch_args, **kwargs})


@pytest.fixture(scope="package")
def browser(launch_browser) -> Iterator[Browser]:
    browser = launch_browser()
    yield browser
    browser.close()


@pytest.fixture(scope="package")
def browser_context_args(base_url: str) -> dict:
    return {"base_url": base_url, "accept_downloads": True}


@pytest.fixture(scope="package", autouse=True)
def _async_unsafe() -> Iterator[None]:
    """Playwright's loop runs in the test thread, which Django's ORM takes for async code; the
    tests' own database calls (and pytest-django's) are ordinary synchronous code."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("DJANGO_ALLOW_ASYNC_UNSAFE", "true")
        yield


@pytest.fixture
def traffic(context: BrowserContext, asgi_server: Server) -> Iterator[Traffic]:
    """Every request of the test's browser context, checked at its end: none answered 4xx or
    5xx, none failed, none left the platform, no script error, every socket got its
    snapshot."""
    watch = Traffic(context, asgi_server.url, server_log=asgi_server.log_tail)
    yield watch
    watch.assert_clean()


@pytest.fixture
def new_page(new_context, asgi_server: Server):
    """Another browser (its own cookies) with its own traffic check: ``new_page()`` returns
    ``(page, traffic)``; the checks run at the end of the test."""
    made: list[Traffic] = []

    def make() -> tuple[Page, Traffic]:
        context = new_context()
        watch = Traffic(context, asgi_server.url, server_log=asgi_server.log_tail)
        made.append(watch)
        return context.new_page(), watch

    yield make
    for watch in made:
        watch.assert_clean()


# --- the system under test ---------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="package")
def media_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Camera pictures: the RV workers write them, the server serves them (one folder)."""
    return tmp_path_factory.mktemp("browser-media")


@dataclass(frozen=True)
class Server:
    url: str
    log: Path

    def log_tail(self, lines: int = 40) -> str:
        """The end of the server's log without the requests that went well."""
        text = self.log.read_text(errors="replace").splitlines()
        return "\n".join([line for line in text if not FINE.search(line)][-lines:])


@pytest.fixture(scope="package")
def asgi_server(
    django_db_setup: None, broker_url: str, media_dir: Path, tmp_path_factory
) -> Iterator[Server]:
    """The platform's ASGI application under daphne, as ``make demo`` runs it, on a free port
    of 127.0.0.1, for this folder's tests (the test database is destroyed after them)."""
    # pytest-django creates the test database only when a test asks for one (django_db): the
    # server must never open the configured database itself.
    configured = dj_database_url.parse(settings.DATABASE_URL)["NAME"]
    assert connection.settings_dict["NAME"] != configured, (
        "browser tests need the test database: mark them django_db(transaction=True)"
    )
    tmp = tmp_path_factory.mktemp("asgi")
    port = _free_port()
    env = {
        **os.environ,
        "DATABASE_URL": database_url(),
        "REDIS_URL": broker_url,
        "CPCC_VAR_DIR": str(tmp / "var"),
        "CPCC_MEDIA_ROOT": str(media_dir),
        "DEBUG": "1",  # as the demo: static files from the apps' folders, no collectstatic
    }
    env.pop("DJANGO_ALLOW_ASYNC_UNSAFE", None)  # the tests' own concern (_async_unsafe)
    log_path = tmp / "daphne.log"
    with log_path.open("ab") as log:
        server = subprocess.Popen(
            [sys.executable, "-m", "daphne", "-b", "127.0.0.1", "-p", str(port), ASGI_APP],
            cwd=ROOT,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    url = f"http://127.0.0.1:{port}"

    def answers() -> bool:
        if server.poll() is not None:
            raise AssertionError(f"daphne exited:\n{log_path.read_text()[-4000:]}")
        try:
            with urllib.request.urlopen(f"{url}/accounts/login/", timeout=2) as response:
                return bool(response.status == 200)
        except OSError:
            return False

    try:
        wait_until(answers, timeout=60, what="daphne to serve the login page")
        yield Server(url=url, log=log_path)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


@pytest.fixture
def feed(broker):
    """The test run's Redis without the map feed of earlier tests (and without their Celery
    messages: see tests/broker.py)."""
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)
    yield broker
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)


@pytest.fixture
def workers(
    broker_url: str, tmp_path: Path, media_dir: Path, feed, transactional_db: None
) -> Iterator[Workers]:
    """Worker processes of this test (``workers.start("rvworker", "Heli One")``), flying at
    SIM_SPEED and writing pictures where the server finds them; stopped at the test's end,
    before its data is flushed."""
    pool = Workers(tmp_path, broker_url, speed=SIM_SPEED)
    pool.env["CPCC_MEDIA_ROOT"] = str(media_dir)
    pool.env.pop("DJANGO_ALLOW_ASYNC_UNSAFE", None)
    try:
        yield pool
    finally:
        pool.stop_all()


class _QuickPBKDF2(PBKDF2PasswordHasher):
    """PBKDF2 with few rounds: the server (default hashers) still checks these passwords."""

    iterations = 1_000


@pytest.fixture(autouse=True)
def _fast_password_hashing(settings) -> None:
    # Replaces tests/conftest.py's MD5, which the server's default hashers do not accept.
    settings.PASSWORD_HASHERS = [f"{__name__}._QuickPBKDF2"]


@dataclass(frozen=True)
class World:
    station: GroundStation
    heli: Vehicle
    customer_a: Customer
    customer_b: Customer


@pytest.fixture
def world(transactional_db: None, feed) -> World:
    """The paper's field: ground station GS Base, RV Heli One over the whole field, Customers
    A and B with a user each (customer-a, customer-b) and a staff user (operator), all with
    tests.browser.pages.PASSWORD."""
    customer_a = CustomerFactory(name="Customer A")
    customer_b = CustomerFactory(name="Customer B")
    UserFactory(username="customer-a", customer=customer_a)
    UserFactory(username="customer-b", customer=customer_b)
    UserFactory(username="operator", is_staff=True, is_superuser=True)
    return World(
        station=GroundStationFactory(name="GS Base"),
        heli=VehicleFactory(name="Heli One", area=FIELD),
        customer_a=customer_a,
        customer_b=customer_b,
    )
