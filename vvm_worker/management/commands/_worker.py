"""What the gsworker and rvworker commands share: the broker, and running Celery."""

from __future__ import annotations

from django.conf import settings

from cpcc_site.celery import app
from cpcc_site.embedded_redis import EmbeddedRedis


def ensure_broker() -> None:
    """Without REDIS_URL, make sure the embedded Redis server runs (started by whichever
    process needs it first; it outlives this worker, as other workers use it too)."""
    if not settings.REDIS_URL:
        EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET).start(detach=True)


def run_celery(*, queues: list[str], node: str, loglevel: str) -> None:
    """A Celery worker on these queues, its tasks run one at a time in this thread."""
    app.worker_main(
        argv=[
            "--quiet",  # no start-up banner: the command prints one line of its own
            "worker",
            "--queues",
            ",".join(queues),
            "--pool",
            "solo",
            "--hostname",
            f"{node}@%h",
            "--without-gossip",
            "--without-mingle",
            "--loglevel",
            loglevel,
        ]
    )
