"""PostgreSQL through psycopg's connection pool (CPCC_DB_POOL_SIZE; the web server's default):
an outage and its end leave the pool serving good connections again, and the outage probe
connects past the pool. A TCP proxy between the processes and the server is cut and restored
(tests/tcp_proxy.py), as in the fault tests. PostgreSQL only (CI's second pass)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import requests
from django.db import OperationalError, connection, connections
from rest_framework.authtoken.models import Token

from cpcc_site import database
from tests.live import Web
from tests.polling import wait_until
from tests.tcp_proxy import TcpProxy

pytestmark = [
    pytest.mark.skipif(
        connection.vendor != "postgresql", reason="the pool is PostgreSQL's (DATABASE_URL)"
    ),
]

ALIAS = "pooled"


@pytest.fixture
def proxy() -> Iterator[TcpProxy]:
    conf = connection.settings_dict
    server = TcpProxy((conf["HOST"] or "127.0.0.1", int(conf["PORT"] or 5432)))
    yield server
    server.close()


@pytest.fixture
def pooled(django_db_blocker, proxy: TcpProxy) -> Iterator[object]:
    """A database alias through the proxy with a pool as settings.py configures one (a size of
    4, all made at once), to the server's maintenance database: it reads no table. Outside a
    test case's transaction: its connections are the pool's."""
    with django_db_blocker.unblock():
        yield from _pooled(proxy)


def _pooled(proxy: TcpProxy) -> Iterator[object]:
    conf = connection.settings_dict
    options = {k: v for k, v in conf["OPTIONS"].items() if k != "pool"}
    options["pool"] = {
        "min_size": 4,
        "max_size": 4,
        "timeout": 5.0,
        "reconnect_timeout": 5.0,
        "max_idle": 300.0,
    }
    connections.settings[ALIAS] = {
        **conf,
        "ENGINE": "cpcc_site.postgresql",
        "NAME": "postgres",
        "HOST": "127.0.0.1",
        "PORT": str(proxy.port),
        "CONN_MAX_AGE": 0,
        "OPTIONS": options,
    }
    try:
        yield connections[ALIAS]
    finally:
        connections[ALIAS].close()
        connections[ALIAS].close_pool()
        del connections[ALIAS]
        del connections.settings[ALIAS]


def query(alias: str = ALIAS) -> int:
    """One request's worth of work: a query on a connection from the pool, given back."""
    conn = connections[alias]
    try:
        with conn.cursor() as cursor:
            cursor.execute("SELECT 1")
            return int(cursor.fetchone()[0])
    finally:
        conn.close()  # back to the pool, as at the end of a request


def serves() -> bool:
    try:
        query()
        return True
    except OperationalError:
        return False


def test_the_pool_serves_good_connections_again_after_an_outage(pooled, proxy) -> None:
    assert query() == 1
    pool = pooled.pool
    pool.wait(timeout=10)  # its connections made, idle in the pool

    # The probe connects past the pool: the pool is not asked for a connection.
    asked = pool.get_stats().get("requests_num", 0)
    assert database.direct_connection(ALIAS).pool is None
    assert database.answers(ALIAS)
    assert pool.get_stats().get("requests_num", 0) == asked

    # An outage while nobody asks: the idle connections break in the pool.
    proxy.cut()
    assert not database.answers(ALIAS)
    proxy.restore()
    assert database.answers(ALIAS)
    # The first request after it gets a good connection (checked one by one, the broken ones
    # would make it wait out the pool's timeout), and so does every one after it.
    assert all(serves() for _ in range(20))

    # An outage while requests come: each is refused as an outage (503 on the web).
    proxy.cut()
    with pytest.raises(OperationalError) as failed:
        query()
    assert database.is_outage(failed.value, ALIAS)
    assert not database.answers(ALIAS)
    proxy.restore()
    wait_until(serves, timeout=15, what="the pool to serve a connection again")
    assert all(serves() for _ in range(20))


@pytest.mark.slow
@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_the_web_server_answers_503_during_an_outage_and_serves_again_after_it(
    web: Web, proxy: TcpProxy, user_a
) -> None:
    conf = connection.settings_dict
    password = f":{conf['PASSWORD']}" if conf["PASSWORD"] else ""
    web.env["DATABASE_URL"] = (
        f"postgres://{conf['USER'] or ''}{password}@127.0.0.1:{proxy.port}/{conf['NAME']}"
    )
    web.env.pop("CPCC_DB_POOL_SIZE", None)  # the web server's default: a pool
    web.start()
    api = requests.Session()
    api.headers["Authorization"] = f"Token {Token.objects.create(user=user_a).key}"
    body = {"name": "after", "program": "VV.log('hello');"}
    assert api.get(web.url("/api/v1/vvs/"), timeout=30).status_code == 200

    proxy.cut()
    refused = api.get(web.url("/api/v1/vvs/"), timeout=30)
    assert refused.status_code == 503, refused.text
    assert refused.headers["Retry-After"] == "5"
    assert api.post(web.url("/api/v1/vvs/"), json=body, timeout=30).status_code == 503

    proxy.restore()
    wait_until(
        lambda: api.get(web.url("/api/v1/vvs/"), timeout=30).status_code == 200,
        timeout=30,
        what="the web server to serve again",
        details=lambda: web.log.read_text()[-3000:],
    )
    answers = [api.get(web.url("/api/v1/vvs/"), timeout=30).status_code for _ in range(20)]
    assert answers == [200] * 20
    created = api.post(web.url("/api/v1/vvs/"), json=body, timeout=30)
    assert created.status_code == 201, created.text
