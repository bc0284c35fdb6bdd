"""The Celery app: the broker is Redis (REDIS_URL, or the embedded server)."""

import os
from typing import Any

from celery import Celery
from celery.signals import task_postrun, task_prerun

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "cpcc_site.settings")

app = Celery("cpcc")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()


@task_prerun.connect
@task_postrun.connect
def _close_old_connections(**kwargs: Any) -> None:
    """Around each task, what Django does around a request: a connection older than its
    CONN_MAX_AGE, or one an error left unusable, is closed (the next query opens a new one)."""
    from django.db import close_old_connections

    close_old_connections()
