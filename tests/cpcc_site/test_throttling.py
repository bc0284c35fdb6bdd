"""The API's request rates counted once for every web process (cpcc_site/throttling.py): two
processes, each with its own Redis client, share one count; while Redis does not answer, each
process counts alone."""

from __future__ import annotations

import logging
import threading

import pytest
import redis
from rest_framework.throttling import SimpleRateThrottle

from cpcc_site import throttling
from tests.api_fixtures import token_client

URL = "/api/v1/vvs/"


@pytest.fixture
def processes(broker_url: str):
    """Two Redis clients of the test run's server, each with its connection pool, as two web
    processes have."""
    clients = [redis.Redis.from_url(broker_url) for _ in range(2)]
    for client in clients:
        throttling.forget_all(client)
    yield clients
    for client in clients:
        throttling.forget_all(client)
        client.close()


def test_two_processes_share_one_count_over_a_sliding_window(processes) -> None:
    one, two = processes
    limit = {"duration": 60.0, "limit": 3}
    assert throttling.hit(one, "throttle_user_1", now=1000.0, **limit) == (True, None)
    assert throttling.hit(two, "throttle_user_1", now=1010.0, **limit) == (True, None)
    assert throttling.hit(one, "throttle_user_1", now=1020.0, **limit) == (True, None)
    # The rate is used up for both, with the time of the oldest request counted.
    assert throttling.hit(two, "throttle_user_1", now=1030.0, **limit) == (False, 1000.0)
    assert throttling.hit(one, "throttle_user_1", now=1059.0, **limit) == (False, 1000.0)
    # Refused requests do not count (DRF's rule): one leaves the window, one comes in.
    assert throttling.hit(two, "throttle_user_1", now=1060.5, **limit) == (True, None)
    assert throttling.hit(one, "throttle_user_1", now=1061.0, **limit) == (False, 1010.0)
    # Another client's count is its own.
    assert throttling.hit(one, "throttle_user_2", now=1061.0, **limit) == (True, None)


def test_requests_at_the_same_moment_in_many_processes_take_exactly_the_rate(
    broker_url: str, processes
) -> None:
    clients = [redis.Redis.from_url(broker_url) for _ in range(8)]
    allowed: list[bool] = []
    start = threading.Barrier(len(clients))

    def requests(client: redis.Redis) -> None:
        start.wait()
        for _ in range(5):
            ok, _ = throttling.hit(client, "throttle_user_9", now=500.0, duration=60.0, limit=17)
            allowed.append(ok)

    threads = [threading.Thread(target=requests, args=(client,)) for client in clients]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(allowed) == 40 and allowed.count(True) == 17
    for client in clients:
        client.close()


def test_the_api_refuses_a_user_whose_requests_another_process_counted(
    user_a, user_b, processes, monkeypatch
) -> None:
    monkeypatch.setattr(SimpleRateThrottle, "THROTTLE_RATES", {"user": "3/min", "address": None})
    a, b = token_client(user_a), token_client(user_b)
    assert [a.get(URL).status_code for _ in range(2)] == [200, 200]
    # Another web process serves user A's third request.
    other, _ = processes
    now = SimpleRateThrottle.timer()
    assert throttling.hit(other, f"throttle_user_{user_a.pk}", now=now, duration=60, limit=3)[0]
    refused = a.get(URL)
    assert refused.status_code == 429
    assert 0 < int(refused["Retry-After"]) <= 60
    assert b.get(URL).status_code == 200  # user B's count is its own


def test_without_redis_each_process_counts_alone_and_says_so(
    user_a, settings, monkeypatch, caplog
) -> None:
    monkeypatch.setattr(SimpleRateThrottle, "THROTTLE_RATES", {"user": "3/min", "address": None})
    monkeypatch.setattr(throttling.OUTAGE, "until", 0.0)  # restored after the test
    settings.CPCC_THROTTLE_REDIS_URL = "unix:///nonexistent/redis.sock"
    a = token_client(user_a)
    with caplog.at_level(logging.WARNING, logger="cpcc.web"):
        assert [a.get(URL).status_code for _ in range(4)] == [200, 200, 200, 429]
    warnings = [r.getMessage() for r in caplog.records if r.name == "cpcc.web"]
    assert len(warnings) == 1 and "counted in this process alone" in warnings[0]


def test_a_request_counts_against_both_rates_in_one_round_trip(
    user_a, processes, monkeypatch
) -> None:
    monkeypatch.setattr(SimpleRateThrottle, "THROTTLE_RATES", {"user": "3/min", "address": "9/min"})
    calls: list[list[str]] = []
    script = throttling._script

    def counting(*, keys, args, client):
        calls.append(list(keys))
        return script(keys=keys, args=args, client=client)

    monkeypatch.setattr(throttling, "_script", counting)
    a = token_client(user_a)
    assert [a.get(URL).status_code for _ in range(4)] == [200, 200, 200, 429]
    assert len(calls) == 4, "one call to Redis a request"
    assert all(len(keys) == 2 for keys in calls), calls
    assert {k.rsplit("_", 1)[0] for k in calls[0]} == {
        "cpcc:throttle_user",
        "cpcc:throttle_address",
    }
    # The refused request counted against the address (which allowed it), not the user.
    other, _ = processes
    now = SimpleRateThrottle.timer()
    assert throttling.hit(other, calls[0][1].removeprefix("cpcc:"), now=now, duration=60, limit=5)[
        0
    ]
    assert not throttling.hit(
        other, calls[0][1].removeprefix("cpcc:"), now=now, duration=60, limit=5
    )[0]
