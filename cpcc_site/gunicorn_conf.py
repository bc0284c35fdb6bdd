"""gunicorn's settings for the platform's HTTP in production: the pages, the REST API and the
static files, answered by WSGI worker processes (``cpcc_site.wsgi``), while daphne
(``cpcc_site.asgi``) holds the live map's sockets (``/ws/``), which a proxy in front routes
there::

    gunicorn -c python:cpcc_site.gunicorn_conf cpcc_site.wsgi
    daphne -b 127.0.0.1 -p 8001 cpcc_site.asgi:application

A request costs about a third less CPU in a WSGI worker than in daphne, which runs each
request's (synchronous) view in a thread of its own (docs/benchmarks.md, issue 23). Options
given on the command line win over these.

- ``CPCC_WEB_BIND``: where to listen (``127.0.0.1:8000``);
- ``CPCC_WEB_WORKERS``: worker processes (two per core: a worker waits for the database and
  Redis for part of each request, and for a client to take its answer);
- each worker warms up before it takes its first request (``cpcc_site.wsgi.warm_up``);
- SIGTERM stops taking connections and lets the requests in progress finish (at most
  ``graceful_timeout``, 20 s, as the workers and daphne do); each worker closes V8 on its
  way out (``vvm_worker.runtime``), exit status 0; a worker on its way out ignores further
  SIGTERMs (``worker_exit``).
"""

from __future__ import annotations

import os
import signal
from typing import Any

from cpcc_site.env import env_float, env_str

bind = env_str("CPCC_WEB_BIND", "127.0.0.1:8000")
workers = int(env_float("CPCC_WEB_WORKERS", 0, minimum=0)) or 2 * (os.cpu_count() or 1)
worker_class = "sync"
graceful_timeout = 20
# A request that takes longer than this (a results archive of a huge VV) is cut off and its
# worker replaced.
timeout = 120
# Django's log settings, not gunicorn's own, for the application; gunicorn's access log off
# (a proxy in front keeps one).
accesslog = None


def post_worker_init(worker: Any) -> None:
    """A worker loaded the application: it warms up before it takes a request."""
    from cpcc_site.wsgi import warm_up

    warm_up()


def worker_exit(server: Any, worker: Any) -> None:
    """A worker is on its way out: further SIGTERMs are ignored until it has exited.

    When the whole process group is stopped (systemd, an operator's ``kill -- -PID``), each
    worker receives SIGTERM twice: from the stop itself, and from the master as it stops its
    workers. Late in an interpreter's shutdown Python gives SIGTERM back its default action, so
    a second SIGTERM that arrives then kills the worker by the signal (gunicorn logs "was sent
    SIGTERM!") before it has closed V8 and exited with status 0. An ignored signal stays
    ignored through that shutdown."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
