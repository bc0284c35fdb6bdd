"""Shared fixtures: always two customers, so every test can show the second one is refused."""

from __future__ import annotations

import contextlib
from pathlib import Path

import pytest

from tests.factories import CustomerFactory, GroundStationFactory, UserFactory, VehicleFactory

# The distributed platform's fixtures (worker processes): see tests/live.py; which tests the
# second pass on PostgreSQL and a Redis server skips: tests/backends.py.
pytest_plugins = ["tests.live", "tests.broker", "tests.backends"]

# The paper's examples (../shared/examples), kept in the repository so a clone is complete.
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCENARIOS = EXAMPLES / "scenarios"
PROGRAMS = EXAMPLES / "vv"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A transactional test must restore what the migrations put in the database (the default
    SDC, content types): one that flushes without it breaks every serialized_rollback test that
    runs after it, far from the cause. Say so at collection instead."""
    for item in items:
        callspec = getattr(item, "callspec", None)
        if (
            callspec is not None
            and "browser_name" in callspec.params
            and "browser" not in str(item.path.parent.name)
        ):
            # A test outside tests/browser that names an argument like one of Playwright's
            # fixtures (page, browser, context) becomes a browser test, and pytest-playwright
            # moves it and every browser test among the database tests.
            raise pytest.UsageError(f"{item.nodeid}: rename the argument Playwright takes")
        marker = item.get_closest_marker("django_db")
        if marker is None:
            continue
        if marker.kwargs.get("transaction") and not marker.kwargs.get("serialized_rollback"):
            raise pytest.UsageError(
                f"{item.nodeid}: django_db(transaction=True) needs serialized_rollback=True "
                "(tests/conftest.py says why)"
            )


def pytest_sessionstart(session: pytest.Session) -> None:
    """Remove what interrupted runs left of their SQLite test databases (a WAL file left
    behind would make a new database fail with a disk I/O error)."""
    from django.conf import settings

    name = settings.DATABASES["default"].get("TEST", {}).get("NAME")
    if not name or not settings.DATABASES["default"]["ENGINE"].endswith("sqlite3"):
        return
    for path in Path(name).parent.glob("test-db-*.sqlite3*"):
        pid = path.name.removeprefix("test-db-").split(".", 1)[0]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            path.unlink(missing_ok=True)


@pytest.fixture(scope="session", autouse=True)
def broker_url(tmp_path_factory: pytest.TempPathFactory):
    """The Redis this test run's Celery messages go to: REDIS_URL's (CI's second pass), or an
    embedded server of the run's own, so that two runs never share queues."""
    from django.conf import settings

    from cpcc_site.celery import app
    from cpcc_site.embedded_redis import EmbeddedRedis

    if settings.REDIS_URL:
        yield settings.REDIS_URL
        return
    socket = tmp_path_factory.mktemp("redis") / "redis.sock"
    with EmbeddedRedis(socket):
        app.conf.broker_url = f"redis+socket://{socket}"
        settings.CPCC_FEED_REDIS_URL = f"unix://{socket}"  # the live map's feed
        settings.CPCC_THROTTLE_REDIS_URL = f"unix://{socket}"  # the API's request counts
        yield f"unix://{socket}"


@pytest.fixture(autouse=True)
def _fast_password_hashing(settings) -> None:
    """Hashing test users' passwords at full strength (about 0.2 s each) would be most of the
    suite's time; no test is about the hasher's strength."""
    settings.PASSWORD_HASHERS = ["django.contrib.auth.hashers.MD5PasswordHasher"]


@pytest.fixture(autouse=True)
def _fresh_cache() -> None:
    """API throttles and login lockouts count in the cache, tokens are remembered: every test
    starts from zero (ids repeat between tests, and every test client comes from 127.0.0.1)."""
    import redis
    from django.core.cache import cache

    from accounts.authentication import TOKENS
    from cpcc_site import throttling

    cache.clear()
    TOKENS.clear()
    with contextlib.suppress(redis.RedisError):  # without Redis, each process counts alone
        throttling.forget_all(throttling.throttle_client())


@pytest.fixture(autouse=True)
def _media_root(settings, tmp_path: Path) -> None:
    """Images of a test go to its own folder, not to var/media."""
    settings.MEDIA_ROOT = tmp_path / "media"


@pytest.fixture
def customer_a(db):
    return CustomerFactory(name="Customer A")


@pytest.fixture
def customer_b(db):
    return CustomerFactory(name="Customer B")


@pytest.fixture
def user_a(customer_a):
    return UserFactory(username="customer-a", customer=customer_a)


@pytest.fixture
def user_b(customer_b):
    return UserFactory(username="customer-b", customer=customer_b)


@pytest.fixture
def staff(db):
    return UserFactory(username="operator", is_staff=True, is_superuser=True)


@pytest.fixture
def ground_station(db):
    return GroundStationFactory(name="GS Base")


@pytest.fixture
def heli_one(db):
    return VehicleFactory(name="Heli One")


@pytest.fixture
def platform(db):
    """The whole platform in one process on discrete-event time, with no scenario loaded:
    add vehicles with ``platform.add_vehicle_loop``, submit VVs with ``platform.vvm`` and run
    everything with ``platform.drain()``."""
    from vvm_worker.simulation import Simulation

    return Simulation(planner="nearest", seed=1)


class RecordingDispatcher:
    """Remembers who the services told to act, and does nothing."""

    def __init__(self) -> None:
        self.arrived: list = []
        self.vehicles: list[int] = []
        self.slots: list[int] = []
        self.wakes: list = []

    def vv_arrived(self, vv_id, *, on=None) -> None:
        self.arrived.append(vv_id)

    def vv_wake_later(self, vv_id, delay_s: float) -> None:
        self.wakes.append((vv_id, delay_s))

    def vehicle_changed(self, vehicle_id: int) -> None:
        self.vehicles.append(vehicle_id)

    def customer_slot_freed(self, customer_id: int) -> None:
        self.slots.append(customer_id)


@pytest.fixture
def vvm_factory(db):
    from fleet.simulation import SensorField
    from vvm_worker.clock import SimulatedClock
    from vvm_worker.services import VVM

    def make() -> VVM:
        return VVM(clock=SimulatedClock(), dispatcher=RecordingDispatcher(), field=SensorField(1))

    return make


@pytest.fixture(autouse=True)
def _fresh_fleet_shape() -> None:
    """Each test's database starts afresh (rolled back): the mapper reads the fleet's shape
    again rather than trust what it saw within its look interval in the test before."""
    from vvm_worker.services import routing

    routing._shape_seen_at = None
    routing._airspace_seen = None
