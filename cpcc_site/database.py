"""Database outages: telling one from a fault of the work, and waiting one out.

An outage is the database server unreachable (refused, reset, timed out), no connection from
the process's pool in time, or, with SQLite, the file locked past its busy timeout. Work that
meets one is not wrong: a worker waits until the database answers and does it again (the work
is transactional, and what it committed before stays committed); the web answers 503 with
Retry-After (cpcc_site.errors). A conflict is an outage of one transaction: PostgreSQL ended
it to break a deadlock with another (or it could not be serialized); nothing of it was
committed and the work is done again at once.

Whether the database answers is asked on a connection of its own, opened past the process's
connection pool (PostgreSQL with CPCC_DB_POOL_SIZE): the pool would hand out a connection it
already holds, perhaps one the outage broke, or make the probe wait for one.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
from collections.abc import Callable
from typing import TypeVar

from django.db import DEFAULT_DB_ALIAS, InterfaceError, OperationalError, connections
from django.db.backends.base.base import BaseDatabaseWrapper

logger = logging.getLogger("cpcc.database")
T = TypeVar("T")

RETRY_AFTER_S = 5  # what a 503 tells a client during an outage
_FIRST_WAIT_S = 0.1
_LONGEST_WAIT_S = 2.0
# SQLite's words for a lock held past the busy timeout (the database is there, but not to us).
_LOCKED = ("database is locked", "database table is locked", "database is busy")
# PostgreSQL's SQLSTATEs for a transaction ended so that another may go on: deadlock detected
# (two transactions took the same rows in opposite orders), serialization failure.
_CONFLICTS = frozenset({"40P01", "40001"})


def answers(alias: str = DEFAULT_DB_ALIAS) -> bool:
    """Whether the database takes a new connection and a query, asked on a connection of its
    own (the caller's may be broken, or inside a transaction), past any pool."""
    probe = direct_connection(alias)
    try:
        with probe.cursor() as cursor:
            cursor.execute("SELECT 1")
            cursor.fetchone()
        return True
    except (OperationalError, InterfaceError):
        return False
    finally:
        with contextlib.suppress(OperationalError, InterfaceError):
            probe.close()


def direct_connection(alias: str = DEFAULT_DB_ALIAS) -> BaseDatabaseWrapper:
    """A new connection (not yet open) to the database, not taken from the process's pool."""
    settings_dict = connections[alias].settings_dict
    options = settings_dict.get("OPTIONS") or {}
    if "pool" not in options:
        return connections.create_connection(alias)
    unpooled = {**settings_dict, "OPTIONS": {k: v for k, v in options.items() if k != "pool"}}
    return type(connections[alias])(unpooled, alias)


def is_outage(exc: BaseException, alias: str = DEFAULT_DB_ALIAS) -> bool:
    """Whether ``exc`` means the database is unavailable, as opposed to a query that is wrong
    (SQLite reports both as OperationalError: the server is asked when in doubt)."""
    if isinstance(exc, InterfaceError):  # the connection was closed under us
        return True
    if not isinstance(exc, OperationalError):
        return False
    if any(words in str(exc).lower() for words in _LOCKED) or _pool_timeout(exc):
        return True
    return is_conflict(exc) or not answers(alias)


def is_conflict(exc: BaseException) -> bool:
    """Whether the server ended the transaction to let another go on (a deadlock between
    two, a serialization failure): nothing of it was committed, and doing it again succeeds
    once the other has finished."""
    return isinstance(exc, OperationalError) and (
        getattr(exc.__cause__, "sqlstate", None) in _CONFLICTS
    )


def _pool_timeout(exc: BaseException) -> bool:
    """The pool had no connection to give in time: every one of its connections busy, or none
    to be made (the server away). Nothing was done: the request can be sent again."""
    pool = sys.modules.get("psycopg_pool")  # not imported: no pool in this process
    return pool is not None and isinstance(exc.__cause__, pool.PoolTimeout)


def wait_until_available(
    stopping: threading.Event | None = None, alias: str = DEFAULT_DB_ALIAS
) -> bool:
    """Wait until the database answers again (backing off to one look every 2 s). Closes this
    thread's connection first, so that the next query opens a new one. False if ``stopping``
    was set meanwhile."""
    stopping = stopping or threading.Event()
    _drop_connection(alias)
    wait = _FIRST_WAIT_S
    while not answers(alias):
        if stopping.wait(wait):
            return False
        wait = min(wait * 2, _LONGEST_WAIT_S)
    logger.warning("database available again")
    return True


def through_outages(work: Callable[[], T], stopping: threading.Event | None = None) -> T:
    """Do ``work``; if it meets a database outage, wait until the database is back and do it
    again (it must be safe to redo: each piece of the platform's work re-reads the state it
    needs, and what it committed stays committed); work that met a conflict is done again at
    once. Any other error, or an outage met while ``stopping`` is set, is raised."""
    while True:
        try:
            return work()
        except Exception as exc:
            if not is_outage(exc):
                raise
            if is_conflict(exc):
                if stopping is not None and stopping.is_set():
                    raise
                # (Not the server: the connection is sound, and the other transaction is
                # done or nearly so.)
                logger.warning("database conflict, doing the work again: %s", _first_line(exc))
                continue
            logger.warning("database unavailable: waiting to do the work again")
            if not wait_until_available(stopping):
                raise


def _first_line(exc: BaseException) -> str:
    return str(exc).partition("\n")[0]


def _drop_connection(alias: str) -> None:
    conn = connections[alias]
    if conn.in_atomic_block:  # only the outermost caller may throw a transaction away
        return
    try:
        conn.close()
    except (OperationalError, InterfaceError):
        conn.connection = None
