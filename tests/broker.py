"""Reading what the platform sent to the broker: the messages waiting in a Celery queue of the
test run's own Redis (kombu's Redis transport keeps a queue as a list named after it)."""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator
from typing import Any

import pytest
import redis

from vvm_worker.dispatch import SHARED_QUEUE


def queued(client: redis.Redis, queue: str) -> list[tuple[str, list[Any]]]:
    """(task name, positional arguments) of every message waiting in ``queue``, oldest first."""
    messages = [json.loads(raw) for raw in reversed(client.lrange(queue, 0, -1))]
    return [(m["headers"]["task"], json.loads(base64.b64decode(m["body"]))[0]) for m in messages]


@pytest.fixture
def broker(broker_url: str) -> Iterator[redis.Redis]:
    """The test run's Redis, its queues emptied before and after the test."""
    client = redis.Redis.from_url(broker_url)

    def empty() -> None:
        for key in client.scan_iter("gs.*"):
            client.delete(key)
        for key in client.scan_iter("rv.*"):
            client.delete(key)
        client.delete(SHARED_QUEUE)

    empty()
    yield client
    empty()
    client.close()
