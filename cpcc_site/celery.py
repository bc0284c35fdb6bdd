"""The Celery app: the broker is Redis (REDIS_URL, or the embedded server)."""

import logging
import os

from celery import Celery, signals

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "cpcc_site.settings")

app = Celery("cpcc")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()


@signals.setup_logging.connect
def _keep_the_platforms_log_lines(loglevel: int | str | None = None, **_: object) -> None:
    """A worker's lines keep the platform's format (Django's LOGGING, cpcc_site/logs.py) from
    its start to its stop. Celery would put its own in place once its worker starts: the lines
    before and after would read differently, and the later ones would lose their fields (the
    VV, the vehicle, the reason). Its ``--loglevel`` still sets the libraries' level."""
    if loglevel:
        logging.getLogger().setLevel(loglevel)
