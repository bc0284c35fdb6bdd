"""What the gsworker and rvworker commands share: the broker, the hosts by name, and running
Celery."""

from __future__ import annotations

import signal
from collections.abc import Sequence
from types import FrameType
from typing import Any

from celery.utils.nodenames import default_nodename, host_format
from celery.worker import state as celery_state
from django.conf import settings
from django.core.management.base import BaseCommand, CommandError
from django.db.models import Model

from cpcc_site.celery import app
from cpcc_site.embedded_redis import EmbeddedRedis
from vvm_worker.hosts import GSHost, RVHost, set_host
from vvm_worker.runtime.pool import POOL


def ensure_broker() -> None:
    """Without REDIS_URL, make sure the embedded Redis server runs (started by whichever
    process needs it first; it outlives this worker, as other workers use it too)."""
    if not settings.REDIS_URL:
        EmbeddedRedis(settings.EMBEDDED_REDIS_SOCKET).start(detach=True)


def run_celery(*, queues: list[str], node: str, loglevel: str, threads: int = 0) -> None:
    """A Celery worker on these queues, its tasks run one at a time in this thread (or, with
    ``threads``, in that many threads): the worker ``celery worker`` makes, without Celery's
    command line (whose import, click-repl and prompt-toolkit among it, was a fifth of a
    worker's start)."""
    pool: dict[str, Any] = (
        {"pool_cls": "threads", "concurrency": threads} if threads else {"pool_cls": "solo"}
    )
    worker = app.Worker(
        hostname=host_format(default_nodename(f"{node}@%h")),
        queues=queues,
        **pool,
        without_gossip=True,
        without_mingle=True,
        loglevel=loglevel,
        quiet=True,  # no start-up banner: the command prints one line of its own
    )
    worker.start()


def prepare_isolates(at_least: int) -> None:
    """Keep at least this many V8 isolates prepared (``CPCC_ISOLATE_POOL`` if more), starting
    now: a VV new to this process starts in one without waiting for it to be made."""
    POOL.size = max(POOL.size, at_least)
    POOL.fill()


def host_named(model: type[Model], name: str, what: str) -> Any:
    """The ground station or vehicle of that name; CommandError listing the names there are."""
    return hosts_named(model, [name], what)[0]


def hosts_named(model: type[Model], names: Sequence[str], what: str) -> list[Any]:
    """The ground stations or vehicles of these names, in their order; a CommandError names
    every unknown one (and one named twice) and lists the names there are."""
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise CommandError(f"{what} named more than once: {', '.join(map(repr, twice))}")
    found = {row.name: row for row in model._default_manager.filter(name__in=names)}
    unknown = [name for name in names if name not in found]
    if unknown:
        known = ", ".join(model._default_manager.order_by("name").values_list("name", flat=True))
        missing = ", ".join(map(repr, unknown))
        plural = "s" if len(unknown) > 1 else ""
        raise CommandError(f"no {what}{plural} named {missing} ({what}s: {known or 'none'})")
    return [found[name] for name in names]


def serve(
    command: BaseCommand, host: GSHost | RVHost, *, queues: list[str], node: str, loglevel: str
) -> None:
    """Run a host's worker: take up its work, then serve its queues until told to stop.

    SIGTERM or SIGINT stops it with exit status 0 at any time: before Celery runs (while the
    host takes up its work) the signal ends the command at once, once the piece of work in
    progress on the host thread is done; from then on Celery's warm shutdown lets the task in
    progress finish (a stop while Celery starts, before its own handlers, asks for the same).
    Either way the host stops before the process ends, and V8 is shut down last
    (vvm_worker.runtime.v8, at exit).
    """
    ensure_broker()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, stop_now)
    set_host(host)
    try:
        host.start()
        command.stdout.write(f"{command_name(host)} {host.name}: queues {', '.join(queues)}")
        command.stdout.flush()
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, stop_celery)
        run_celery(queues=queues, node=node, loglevel=loglevel)
    finally:
        host.stop()
        set_host(None)


def stop_now(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(0)


def stop_celery(signum: int, frame: FrameType | None) -> None:
    """A stop while Celery starts (before its own handlers, which do the same): its warm
    shutdown, as soon as its loop runs, rather than an exception raised into its start-up."""
    celery_state.should_stop = 0


def command_name(host: GSHost | RVHost) -> str:
    return "rvworker" if isinstance(host, RVHost) else "gsworker"
