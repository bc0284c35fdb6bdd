"""Redis: the embedded server a fresh machine runs, and the one REDIS_URL names."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path

import redis
from kombu import Connection

from cpcc_site.embedded_redis import EmbeddedRedis, answers


def test_the_embedded_server_starts_serves_celery_and_stops(tmp_path: Path) -> None:
    socket = tmp_path / "redis.sock"
    with EmbeddedRedis(socket) as server:
        client = redis.Redis(unix_socket_path=str(socket))
        client.set("cpcc", "yes")
        assert client.get("cpcc") == b"yes"
        # The Celery broker URL the settings build for the embedded server.
        with Connection(f"redis+socket://{socket}") as conn:
            conn.ensure_connection(max_retries=1)
        # A second user of the same socket finds it running and does not start another.
        again = EmbeddedRedis(socket).start()
        assert again.process is None
        assert server.process is not None
    assert not answers(socket)
    assert not socket.exists()


def test_the_configured_broker_and_channel_layer_answer(settings) -> None:
    """With REDIS_URL (CI's second pass) the real server, otherwise the embedded one."""
    with EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET) if not settings.REDIS_URL else nullcontext():
        with Connection(settings.CELERY_BROKER_URL) as conn:
            conn.ensure_connection(max_retries=1)
        host = settings.CHANNEL_LAYERS["default"]["CONFIG"]["hosts"][0]
        assert redis.Redis.from_url(host).ping()
