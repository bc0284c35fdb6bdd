"""The live map's feed from an RV worker's host: the changes a piece of work committed reach
Redis together, in one round trip, in the order they were made; a change rolled back (with its
savepoint or its transaction) never does."""

from __future__ import annotations

import json
import threading
import time

import pytest
import redis
from django.db import transaction

from missions.events import EVENTS_STREAM
from vvm_worker.live import PUBLISH_INTERVAL_S, FeedAnnouncer

pytestmark = pytest.mark.django_db


class CountingRedis(redis.Redis):
    """The test run's Redis, counting the pipelines sent to it."""

    pipelines = 0

    def pipeline(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        pipe = super().pipeline(*args, **kwargs)
        execute = pipe.execute

        def counted(*a, **k):  # type: ignore[no-untyped-def]
            type(self).pipelines += 1
            return execute(*a, **k)

        pipe.execute = counted  # type: ignore[method-assign]
        return pipe


@pytest.fixture
def client(broker, broker_url):
    broker.delete(EVENTS_STREAM)
    CountingRedis.pipelines = 0
    client = CountingRedis.from_url(broker_url)
    yield client
    client.close()
    broker.delete(EVENTS_STREAM)


def published(client: redis.Redis) -> list[int]:
    return [json.loads(fields[b"e"])["n"] for _, fields in client.xrange(EVENTS_STREAM)]


def test_a_pieces_committed_changes_go_out_in_one_round_trip_at_its_flush(
    client, django_capture_on_commit_callbacks
) -> None:
    feed = FeedAnnouncer(client, batched=True)
    with django_capture_on_commit_callbacks(execute=True), transaction.atomic():
        feed.announce({"n": 1})
        try:
            with transaction.atomic():  # a savepoint, rolled back
                feed.announce({"n": 2})
                raise ValueError("rolled back")
        except ValueError:
            pass
        feed.announce({"n": 3})
    with django_capture_on_commit_callbacks(execute=True):
        feed.announce({"n": 4})  # outside a transaction: committed at once
    assert published(client) == []  # nothing before the flush
    feed.flush()
    assert published(client) == [1, 3, 4]
    assert CountingRedis.pipelines == 1
    feed.flush()  # nothing waits: no round trip
    assert CountingRedis.pipelines == 1


def test_a_change_whose_transaction_rolls_back_is_never_published(
    client, django_capture_on_commit_callbacks
) -> None:
    feed = FeedAnnouncer(client, batched=True)
    with django_capture_on_commit_callbacks(execute=True):
        try:
            with transaction.atomic():
                feed.announce({"n": 1})
                raise ValueError("rolled back")
        except ValueError:
            pass
    feed.flush()
    assert published(client) == []


def test_unbatched_each_change_is_published_as_its_transaction_commits(
    client, django_capture_on_commit_callbacks
) -> None:
    feed = FeedAnnouncer(client)
    with django_capture_on_commit_callbacks(execute=True):
        with transaction.atomic():
            feed.announce({"n": 1})
            feed.announce({"n": 2})
        assert published(client) == []
    assert published(client) == [1, 2]


def test_in_the_background_the_host_thread_never_waits_and_close_publishes_what_waits(
    client, django_capture_on_commit_callbacks
) -> None:
    """An RV worker's feed: flushes return at once (Redis is held up here, and the flushes
    still return), and everything reaches the stream in the order it committed by `close`."""
    feed = FeedAnnouncer(client, batched=True, in_background=True)
    held = threading.Event()
    publish = feed._publish

    def held_publish(events: list[str]) -> None:
        held.wait(10)  # Redis slow: the publisher waits, never the caller of flush
        publish(events)

    feed._publish = held_publish  # type: ignore[method-assign]
    for n in range(1, 6):
        with django_capture_on_commit_callbacks(execute=True), transaction.atomic():
            feed.announce({"n": n})
        feed.flush()
    assert published(client) == []  # all handed over, none sent yet
    held.set()
    feed.close()
    assert published(client) == [1, 2, 3, 4, 5]
    assert CountingRedis.pipelines <= 2  # what waited went out together


def test_in_the_background_a_burst_of_flushes_goes_out_in_one_round_trip_an_interval(
    client, django_capture_on_commit_callbacks
) -> None:
    """A busy host flushes after every piece of work: Redis gets one round trip per
    PUBLISH_INTERVAL_S at most (the first at once), with everything in order."""
    feed = FeedAnnouncer(client, batched=True, in_background=True)
    started = time.monotonic()
    for n in range(1, 41):
        with django_capture_on_commit_callbacks(execute=True), transaction.atomic():
            feed.announce({"n": n})
        feed.flush()
    feed.close()
    elapsed = time.monotonic() - started
    assert published(client) == list(range(1, 41))
    assert CountingRedis.pipelines <= 2 + elapsed / PUBLISH_INTERVAL_S


def test_in_the_background_needs_batches() -> None:
    with pytest.raises(ValueError, match="batched"):
        FeedAnnouncer(in_background=True)
