"""Redis: the embedded server a fresh machine runs, and the one REDIS_URL names."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
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


STARTER = """
import sys
from pathlib import Path

import redis

from cpcc_site.embedded_redis import EmbeddedRedis

socket = Path(sys.argv[1])
sys.stdin.readline()  # every starter goes at once
EmbeddedRedis(socket).start(detach=True)
print(redis.Redis(unix_socket_path=str(socket)).info("server")["process_id"])
"""


def _servers_on(socket: Path) -> list[int]:
    """The redis-server processes started for this socket."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            command = (entry / "cmdline").read_bytes()
        except (OSError, ValueError):
            continue
        if entry.name.isdigit() and b"redis-server" in command and str(socket).encode() in command:
            found.append(int(entry.name))
    return found


def test_workers_started_together_share_one_embedded_server(tmp_path: Path) -> None:
    socket = tmp_path / "redis.sock"
    root = Path(__file__).resolve().parents[2]
    starters = [
        subprocess.Popen(
            [sys.executable, "-c", STARTER, str(socket)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=root,
        )
        for _ in range(3)
    ]
    try:
        for starter in starters:
            assert starter.stdin is not None
            starter.stdin.write("go\n")
            starter.stdin.flush()
        answered = {int(s.communicate(timeout=60)[0].strip()) for s in starters}
        assert len(answered) == 1
        assert _servers_on(socket) == list(answered)
    finally:
        for pid in _servers_on(socket):
            os.kill(pid, signal.SIGTERM)
