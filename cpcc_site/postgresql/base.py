"""Django's PostgreSQL backend whose pool (``OPTIONS["pool"]``) drains itself when it finds a
broken connection, so that it serves good ones again as soon as the database is back after an
outage."""

from __future__ import annotations

from typing import Any

from django.db.backends.base.base import NO_DB_ALIAS
from django.db.backends.postgresql import base
from psycopg_pool import ConnectionPool


def check_connection(conn: Any) -> None:
    """The pool's check of a connection it is about to hand out: psycopg_pool's own (an empty
    query) which, on a broken connection, also drains the pool.

    A connection that broke while it waited in the pool says, most likely, that the database
    went away (an outage, a restart) and broke all of them. Checked one by one, each broken
    one would cost the request a growing back-off (1 s, 2 s, ...: psycopg_pool's getconn), so
    that after an outage the first requests would wait out the pool's timeout although the
    database is back; drained, the pool makes new connections at once and the request gets one
    on its next try. Raises what the check raised.
    """
    try:
        ConnectionPool.check_connection(conn)
    except Exception:
        pool = getattr(conn, "_pool", None)  # its pool, while it is out of the pool
        if pool is not None:
            pool.drain()
        raise


class DatabaseWrapper(base.DatabaseWrapper):
    """Django's PostgreSQL connection, with its pool made as Django makes it (Django 5.2's
    ``pool``) but checked by ``check_connection``: Django passes only psycopg_pool's own check
    (CONN_HEALTH_CHECKS), and refuses another in the pool's options."""

    @property
    def pool(self) -> ConnectionPool | None:
        options = self.settings_dict["OPTIONS"].get("pool")
        if self.alias == NO_DB_ALIAS or not options:
            return None
        # Django's pools, by alias, for the whole class (close_pool removes one).
        pools: dict[str, ConnectionPool] = self._connection_pools  # type: ignore[attr-defined]
        if self.alias not in pools:
            connect_kwargs = self.get_connection_params()
            connect_kwargs["autocommit"] = True  # Django sets the mode it wants after
            pool = ConnectionPool(
                kwargs=connect_kwargs,
                open=False,  # opened by the first connection (get_new_connection)
                configure=self._configure_connection,  # type: ignore[attr-defined]
                check=check_connection,
                **({} if options is True else options),
            )
            # Two threads may make one at once: the first one stored is the pool.
            pools.setdefault(self.alias, pool)
        return pools[self.alias]
