"""A unit of work in the store: one transaction, pipelined, and new rows sent without waiting."""

from __future__ import annotations

import contextlib
import datetime as dt
from collections.abc import Iterator, Sequence

from django.db import DatabaseError, models
from django.db.models import DateTimeField, ExpressionWrapper
from django.db.models.functions import Now

from cpcc_site import database
from cpcc_site.prepared import deferred, insert_rows, pipelined_transaction


class StepBroke(Exception):
    """The platform could not run a VV's step or apply its result: a bug of the platform (not
    a database outage), which would happen again on every retry."""

    def __init__(self, cause: Exception) -> None:
        super().__init__(f"{type(cause).__name__}: {cause}")
        self.cause = cause


@contextlib.contextmanager
def unit_of_work() -> Iterator[None]:
    """A VV's unit of work: one transaction, pipelined. A statement the database refuses
    (a platform bug: a step's writes are checked before they are sent; a deferred one is
    refused at the next statement that waits, or when the block ends) raises StepBroke, as a
    step the platform cannot apply does; a database outage is raised as it is, for the
    caller to wait out and redo."""
    try:
        with pipelined_transaction():
            yield
    except DatabaseError as exc:
        if database.is_outage(exc):
            raise
        raise StepBroke(exc) from exc


def rows_add(rows: Sequence[models.Model]) -> None:
    """New rows (tasks, a message, a migration, a log line) of one model, in one INSERT sent
    without waiting: their keys are set by the end of the unit of work (in a pipelined one;
    at once elsewhere), and a refusal fails it."""
    if rows:
        with deferred():
            insert_rows(list(rows))


def db_time_ago(seconds: float) -> ExpressionWrapper:
    """That long ago by the database's clock: the same for every worker, whatever its own
    clock says (leases, sweeps)."""
    return ExpressionWrapper(Now() - dt.timedelta(seconds=seconds), output_field=DateTimeField())
