"""The Celery app: the broker is Redis (REDIS_URL, or the embedded server)."""

import os

from celery import Celery

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "cpcc_site.settings")

app = Celery("cpcc")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()
