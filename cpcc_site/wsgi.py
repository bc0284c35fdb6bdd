"""The WSGI application (gunicorn's workers, cpcc_site/gunicorn_conf.py) and its warm-up."""

import logging
import os

from django.core.wsgi import get_wsgi_application

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "cpcc_site.settings")
application = get_wsgi_application()

logger = logging.getLogger("cpcc.web")


def warm_up() -> None:
    """What a worker's first requests would otherwise pay for, done before it takes one
    (gunicorn's ``post_worker_init``): every view imported (the URLconf resolved), V8 ready
    to check a program's syntax, and the machinery of the messages a submission sends to
    the workers (Celery's producer and its broker connection): 150 ms of the first GET and
    POST. Redis away: its part is left to the first request that needs it."""
    from django.urls import get_resolver

    from cpcc_site.celery import app
    from vvm_worker.runtime.syntax import check_syntax

    get_resolver().reverse_dict  # noqa: B018 (the URLconf and every view module imported)
    check_syntax("")
    app.AsyncResult  # noqa: B018 (what sending a message imports)

    try:
        with app.producer_or_acquire() as producer:
            producer.connection.ensure_connection(max_retries=0)
    except Exception as exc:  # the worker serves pages without Redis: not a reason to stop
        logger.warning("web worker warm-up: no broker connection yet (%s)", exc)
