"""The Celery app as the workers run it."""

from __future__ import annotations

import pytest
from celery.fixups.django import DjangoWorkerFixup
from celery.signals import task_postrun
from django.db import connection

from cpcc_site.celery import app


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_a_worker_keeps_its_database_connection_from_one_task_to_the_next() -> None:
    # Celery's Django fix-up would close it after every task: a new connection (a new
    # PostgreSQL process) for every message a worker takes.
    connection.ensure_connection()
    before = connection.connection
    DjangoWorkerFixup(app).close_database()
    assert connection.connection is before


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_after_a_task_a_connection_an_error_left_unusable_is_closed() -> None:
    connection.ensure_connection()
    connection.errors_occurred = True
    connection.connection.close()  # what a database restart does to it
    task_postrun.send(sender=None)
    assert connection.connection is None
