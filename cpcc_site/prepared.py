"""Statements made again and again (at every task of an RV, at every API request), written once.

Django compiles a queryset's SQL each time it runs: for a VV's row with its customer and hosts
(about 90 columns over four tables) that is half a millisecond, five times the time the
database takes to answer. A ``PreparedRead`` compiles its queryset once per database and
runs the same SQL again with new parameters, building the model instances (and the related
ones of ``select_related``) exactly as a queryset would, or giving its rows or their count;
``PreparedPages`` hands such a read to a paginator. The writes (``insert_rows``,
``save_fields``, ``update_row``) write their SQL themselves, once per model and shape, for
models whose save signals nobody listens to.

On PostgreSQL a unit of work may run ``pipelined``: the writes it marks ``deferred`` go to the
server without waiting for their answers, which come back with the next statement that waits
(every other one does, as outside a pipeline), and their checks run when the block ends. A
unit that is a transaction of its own (``pipelined_transaction``) sends its BEGIN with its
first statements and its COMMIT with its last writes when no check waits for their answers:
two round trips fewer than psycopg would make.

Django's parts used here that its documentation does not promise are named in
``DJANGO_INTERNALS`` (with the signatures this module relies on);
tests/cpcc_site/test_django_internals.py fails when a Django release changes one of them, and
``pyproject.toml`` keeps Django within one minor version.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

from django.db import DatabaseError, connections, models, transaction
from django.db.models.query import get_related_populators
from psycopg import IsolationLevel
from psycopg.pq import TransactionStatus

M = TypeVar("M", bound=models.Model)

# The undocumented parts of Django this module stands on: callables by their dotted path, with
# the signature it calls them by, and attributes (of a compiled read, a connection, an
# instance) checked on real objects by the test.
DJANGO_INTERNALS: dict[str, str] = {
    "django.db.models.query.get_related_populators": "(klass_info, select, db)",
    "django.db.models.sql.query.Query.get_compiler": (
        "(self, using=None, connection=None, elide_empty=True)"
    ),
    "django.db.models.sql.compiler.SQLCompiler.as_sql": (
        "(self, with_limits=True, with_col_aliases=False)"
    ),
    "django.db.models.sql.compiler.SQLCompiler.get_converters": "(self, expressions)",
    "django.db.models.sql.compiler.SQLCompiler.apply_converters": "(self, rows, converters)",
    "django.db.backends.base.base.BaseDatabaseWrapper.make_cursor": "(self, cursor)",
    "SQLCompiler.select": "[(column, sql, alias)], a column's .target.attname",
    "SQLCompiler.klass_info": "{model, select_fields, related_klass_infos}",
    "SQLCompiler.annotation_col_map": "{name: index}",
    "Model._state": ".adding, .db",
    "Options.local_concrete_fields": "the fields with a column of their own",
    "BaseDatabaseWrapper": (
        ".atomic_blocks, .savepoint_ids, .needs_rollback, .in_atomic_block, "
        ".queries_logged, .wrap_database_errors, .ensure_connection()"
    ),
}


@dataclass(frozen=True)
class Many:
    """The sample of a key that is a list: ``marker(i)`` is its i-th value, one the query
    holds nowhere else."""

    marker: Callable[[int], Any]


class PreparedRead(Generic[M]):
    """``build(*keys)`` is a queryset that selects rows by the values ``keys`` (a primary key,
    say, and the customer the row must belong to); ``first(*keys)``, ``all``, ``rows`` and
    ``count`` run it for other values.
    ``samples`` names the model's field of each key (``pk`` or a field's name or attname) and a
    value of it that the query holds nowhere else (to find its place among the parameters);
    a key that is a list (``pk__in=keys``) has a ``Many`` sample, and the query is compiled
    once for each length of list it is given (up to _CACHED_ROWS; longer ones at each run). The queryset may use ``select_related``,
    annotations and ``select_for_update`` (then it must run in a transaction, as the queryset
    would). Safe to share between threads."""

    def __init__(
        self, build: Callable[..., models.QuerySet[M]], *, samples: Sequence[tuple[str, Any]]
    ) -> None:
        self.build = build
        self.samples = list(samples)
        self._compiled: dict[tuple[Any, ...], tuple[Any, str, list[Any], list[list[int]]]] = {}

    def first(self, *keys: Any, using: str = "default") -> M | None:
        """The first row for these keys (the query as compiled: no LIMIT is added, so a
        locking read stays as the queryset wrote it)."""
        found = self._objects(keys, None, 0, using, first=True)
        return found[0] if found else None

    def all(
        self, *keys: Any, limit: int | None = None, offset: int = 0, using: str = "default"
    ) -> list[M]:
        """The rows for these keys, in the queryset's order: ``limit`` of them (None: all)
        from ``offset`` on, as slicing the queryset gives them."""
        return self._objects(keys, limit, offset, using)

    def first_later(self, *keys: Any, using: str = "default") -> Callable[[], M | None]:
        """``first``, sent now and read when the function it gives back is called: inside
        ``pipelined``, the statements sent in between go to the server with it and their
        answers come back together, in one round trip (the reader must be called before the
        block ends; outside a pipeline the read is done at once)."""
        compiler, sql, params = self._bound(keys, using)
        row_later = send_later(sql, params, using=using)

        def read() -> M | None:
            row = row_later()
            found = self._build(compiler, [] if row is None else [row], using)
            return found[0] if found else None

        return read

    def _objects(
        self, keys: Sequence[Any], limit: int | None, offset: int, using: str, first: bool = False
    ) -> list[M]:
        compiler, sql, params = self._bound(keys, using)
        if limit is not None:
            sql, params = f"{sql} LIMIT %s OFFSET %s", [*params, limit, offset]
        elif offset:
            raise ValueError("an offset needs a limit")
        with connections[using].cursor() as cursor:
            cursor.execute(sql, params)
            if first:
                row = cursor.fetchone()
                rows = [] if row is None else [row]
            else:
                rows = cursor.fetchall()
        return self._build(compiler, rows, using)

    def _build(self, compiler: Any, rows: Sequence[Any], using: str) -> list[M]:
        """Model instances from rows as ``compiler`` selected them."""
        if not rows:
            return []
        plan = getattr(compiler, _BUILD_PLAN, None)
        if plan is None:
            plan = _BuildPlan.of(compiler, using)
            setattr(compiler, _BUILD_PLAN, plan)  # (read again with this compiler, if cached)
        if plan.converters:
            rows = list(compiler.apply_converters(rows, plan.converters))
        model, names, start, end = plan.model, plan.names, plan.start, plan.end
        populators, annotations = plan.populators, plan.annotations
        found: list[M] = []
        for row in rows:
            obj: M = model.from_db(using, names, row[start:end])
            for populator in populators:
                populator.populate(row, obj)
            for name, at in annotations:
                setattr(obj, name, row[at])
            found.append(obj)
        return found

    def count(self, *keys: Any, using: str = "default") -> int:
        """How many rows there are for these keys (what ``queryset.count()`` says)."""
        _, sql, params = self._bound(keys, using)
        with connections[using].cursor() as cursor:
            cursor.execute(f"SELECT COUNT(*) FROM ({sql}) counted", params)
            return int(cursor.fetchone()[0])

    def _bound(self, keys: Sequence[Any], using: str) -> tuple[Any, str, list[Any]]:
        """The compiled query, its SQL and its parameters with these keys in their places."""
        connection = connections[using]
        pairs = zip(self.samples, keys, strict=True)
        lengths = tuple(len(key) for (_, sample), key in pairs if isinstance(sample, Many))
        compiled = self._compiled.get((using, connection.vendor, lengths))
        if compiled is None:
            compiled = self._compile(using, lengths)
            if all(length <= _CACHED_ROWS for length in lengths):  # longer lists: each time
                self._compiled[(using, connection.vendor, lengths)] = compiled
        compiler, sql, params, places = compiled
        params = [*params]
        for (name, sample), at, key in zip(self.samples, places, keys, strict=True):
            field = self._field(compiler.query.model, name)
            values = key if isinstance(sample, Many) else [key]
            for where, value in zip(at, values, strict=True):
                params[where] = field.get_db_prep_value(value, connection)
        return compiler, sql, params

    def rows(self, *keys: Any, using: str = "default") -> list[tuple[Any, ...]]:
        """Every row of a ``values_list`` queryset for these keys, as tuples (the columns
        converted as the queryset would)."""
        compiler, sql, params = self._bound(keys, using)
        with connections[using].cursor() as cursor:
            cursor.execute(sql, params)
            found = cursor.fetchall()
        return self._converted(compiler, found)

    def rows_later(self, *keys: Any, using: str = "default") -> Callable[[], list[tuple[Any, ...]]]:
        """``rows``, sent now and read when the function it gives back is called (as
        ``first_later``)."""
        compiler, sql, params = self._bound(keys, using)
        found_later = send_later_rows(sql, params, using=using)
        return lambda: self._converted(compiler, found_later())

    @staticmethod
    def _converted(compiler: Any, found: list[Any]) -> list[tuple[Any, ...]]:
        converters = _converters(compiler)
        if converters:
            found = [tuple(row) for row in compiler.apply_converters(found, converters)]
        return found

    @staticmethod
    def _field(model: type[models.Model], name: str) -> Any:
        return model._meta.pk if name == "pk" else model._meta.get_field(name)

    def _compile(
        self, using: str, lengths: tuple[int, ...] = ()
    ) -> tuple[Any, str, list[Any], list[list[int]]]:
        connection = connections[using]
        sizes = iter(lengths)
        given = [
            [value.marker(i) for i in range(next(sizes))] if isinstance(value, Many) else value
            for _, value in self.samples
        ]
        queryset = self.build(*given)
        compiler = queryset.query.get_compiler(using=using)
        sql, params = compiler.as_sql()
        at = []
        for (name, sample), value in zip(self.samples, given, strict=True):
            field = self._field(queryset.model, name)
            where = []
            for one in value if isinstance(sample, Many) else [value]:
                marker = field.get_db_prep_value(one, connection)
                places = [i for i, param in enumerate(params) if param == marker]
                if len(places) != 1:
                    raise ValueError(
                        f"the key {name} must appear once among the parameters: {places}"
                    )
                where.append(places[0])
            at.append(where)
        return compiler, sql, list(params), at


# What a compiled read works out once (kept on its compiler, which is kept with its SQL).
_BUILD_PLAN = "_cpcc_build_plan"
_CONVERTERS = "_cpcc_converters"


def _converters(compiler: Any) -> dict[int, Any]:
    """The converters of the compiled read's columns, worked out at its first read."""
    converters = getattr(compiler, _CONVERTERS, None)
    if converters is None:
        converters = compiler.get_converters([column for column, _, _ in compiler.select])
        setattr(compiler, _CONVERTERS, converters)
    return converters


@dataclass(frozen=True)
class _BuildPlan:
    """How a compiled read's rows become model instances: what Django works out for each
    queryset it runs (the columns' converters, the fields' names, the related objects'
    populators), worked out once per compiled read. Nothing in it changes with the rows."""

    model: type[models.Model]
    converters: dict[int, Any]
    names: list[str]
    start: int
    end: int
    populators: list[Any]
    annotations: list[tuple[str, int]]

    @classmethod
    def of(cls, compiler: Any, using: str) -> _BuildPlan:
        select, klass_info = compiler.select, compiler.klass_info
        fields = klass_info["select_fields"]
        start, end = fields[0], fields[-1] + 1
        return cls(
            model=klass_info["model"],
            converters=_converters(compiler),
            names=[column.target.attname for column, _, _ in select[start:end]],
            start=start,
            end=end,
            populators=get_related_populators(klass_info, select, using),
            annotations=list(compiler.annotation_col_map.items()),
        )


class PreparedPages(Generic[M]):
    """The rows of a ``PreparedRead`` for these keys as a paginator takes them (Django's
    ``Paginator``, DRF's pagination): ``count()`` and slices, each one statement written once.
    ``each`` is done to every row read (to give it a related object the caller has, say).
    No read (None): no rows."""

    ordered = True  # (the paginator asks)

    def __init__(
        self,
        read: PreparedRead[M] | None,
        keys: Sequence[Any],
        *,
        each: Callable[[M], Any] | None = None,
    ) -> None:
        self._read, self._keys, self._each = read, list(keys), each

    def count(self) -> int:
        return 0 if self._read is None else self._read.count(*self._keys)

    def __len__(self) -> int:
        return self.count()

    def __getitem__(self, wanted: slice) -> list[M]:
        start, stop = wanted.start or 0, wanted.stop
        if self._read is None or (stop is not None and stop <= start):
            return []
        if stop is None:
            found = self._read.all(*self._keys)[start:]
        else:
            found = self._read.all(*self._keys, limit=stop - start, offset=start)
        if self._each is not None:
            for obj in found:
                self._each(obj)
        return found


_UPDATES: dict[tuple[Any, ...], tuple[str, list[Any]]] = {}


def save_fields(
    obj: models.Model, fields: Sequence[str], *, held: bool = False, using: str = "default"
) -> None:
    """``obj.save(update_fields=fields)`` for a model without save signals that anyone
    listens to, with its SQL compiled once per model and set of fields: one ``UPDATE`` by the
    primary key. Fields that set themselves (``auto_now``) do so as in ``save``. Raises
    ``DatabaseError``, as ``save`` does, if the row is not there.

    ``held``: the caller's transaction holds the row locked (``select_for_update``), so it is
    there: nothing to check, and a deferred write waits for no answer, which lets its unit of
    work commit with it (``pipelined_transaction``)."""
    connection = connections[using]
    model = type(obj)
    key = (model, tuple(fields), connection.vendor)
    compiled = _UPDATES.get(key)
    if compiled is None:
        meta, quote = model._meta, connection.ops.quote_name
        targets = [meta.get_field(name) for name in fields]
        columns = ", ".join(f"{quote(field.column)} = %s" for field in targets)
        sql = f"UPDATE {quote(meta.db_table)} SET {columns} WHERE {quote(meta.pk.column)} = %s"
        compiled = _UPDATES[key] = (sql, targets)
    sql, targets = compiled
    params = [field.get_db_prep_save(field.pre_save(obj, False), connection) for field in targets]
    params.append(model._meta.pk.get_db_prep_value(obj.pk, connection))

    def check(cursor: Any) -> None:
        if cursor.rowcount != 1:
            raise DatabaseError(f"{model.__name__} {obj.pk}: no row to update")

    _execute(connection, sql, params, None if held else check, checks=not held)


def update_row(
    model: type[models.Model],
    pk: Any,
    *,
    values: Mapping[str, Any],
    add: Mapping[str, Any] | None = None,
    using: str = "default",
) -> int | None:
    """``model.objects.filter(pk=pk).update(**values, **{f: F(f) + n for f, n in add})`` with
    its SQL written once per model and fields (the ORM compiles an update at every call): one
    ``UPDATE`` by the primary key; fields that set themselves are left as ``update`` leaves
    them. The number of rows changed (0: no such row; None when ``deferred``: not known
    yet)."""
    connection = connections[using]
    sql, params = _update_statement(model, pk, values, add or {}, connection)
    changed: list[int] = []
    _execute(connection, sql, params, lambda cursor: changed.append(int(cursor.rowcount)))
    return changed[0] if changed else None


def update_row_with(
    model: type[models.Model],
    pk: Any,
    *,
    values: Mapping[str, Any],
    add: Mapping[str, Any] | None = None,
    write: tuple[str, Sequence[Any]],
    using: str = "default",
) -> None:
    """``update_row`` and another write (``write``: its SQL and parameters; it must not read
    the updated row) as one statement on PostgreSQL, the update a data-modifying ``WITH`` in
    front of the other; elsewhere two statements, the other first. Whether the row was there
    is not told."""
    connection = connections[using]
    sql, params = _update_statement(model, pk, values, add or {}, connection)
    other_sql, other_params = write
    if connection.vendor == "postgresql":
        _execute(
            connection, f'WITH "updated" AS ({sql}) {other_sql}', [*params, *other_params], None
        )
        return
    _execute(connection, other_sql, list(other_params), None)
    _execute(connection, sql, params, None)


def _update_statement(
    model: type[models.Model],
    pk: Any,
    values: Mapping[str, Any],
    add: Mapping[str, Any],
    connection: Any,
) -> tuple[str, list[Any]]:
    """``update_row``'s statement and parameters (its SQL written once per model and fields)."""
    key = (model, tuple(values), tuple(add), connection.vendor)
    compiled = _UPDATES.get(key)
    if compiled is None:
        meta, quote = model._meta, connection.ops.quote_name
        targets = [meta.get_field(name) for name in (*values, *add)]
        columns = [f"{quote(field.column)} = %s" for field in targets[: len(values)]]
        columns += [
            f"{quote(field.column)} = {quote(field.column)} + %s"
            for field in targets[len(values) :]
        ]
        sql = f"UPDATE {quote(meta.db_table)} SET {', '.join(columns)} WHERE {quote(meta.pk.column)} = %s"
        compiled = _UPDATES[key] = (sql, targets)
    sql, targets = compiled
    given = [*values.values(), *add.values()]
    params = [
        field.get_db_prep_save(value, connection)
        for field, value in zip(targets, given, strict=True)
    ]
    params.append(model._meta.pk.get_db_prep_value(pk, connection))
    return sql, params


_INSERTS: dict[tuple[Any, ...], tuple[str, list[Any]]] = {}
# Parameters of one INSERT at most (SQLite takes 32,766, PostgreSQL 65,535): more rows go in
# several. Statements of up to _CACHED_ROWS rows are written once, longer ones each time.
_MAX_PARAMS = 30_000
_CACHED_ROWS = 16


def insert_rows(
    objs: Sequence[models.Model],
    *,
    on_conflict: str | None = None,
    unique_fields: Sequence[str] = (),
    update_fields: Sequence[str] = (),
    using: str = "default",
) -> None:
    """``bulk_create(objs)`` for a model without save signals that anyone listens to, with its
    SQL written once per model, number of rows and conflict handling: one ``INSERT`` of every
    concrete field but an automatic primary key, which each new row's object then has.

    ``on_conflict``: None (a conflict raises ``IntegrityError``), ``"ignore"`` (a row that
    conflicts is not inserted; no key is given back) or ``"update"`` (the row that conflicts
    on ``unique_fields`` takes ``update_fields`` from the new one; no key is given back).
    Fields that set themselves (``auto_now``, defaults) do so as in ``bulk_create``."""
    if not objs:
        return
    connection = connections[using]
    model = type(objs[0])
    meta = model._meta
    per_statement = max(1, _MAX_PARAMS // len(meta.local_concrete_fields))
    if len(objs) > per_statement:
        for start in range(0, len(objs), per_statement):
            insert_rows(
                objs[start : start + per_statement],
                on_conflict=on_conflict,
                unique_fields=unique_fields,
                update_fields=update_fields,
                using=using,
            )
        return
    key = (model, len(objs), on_conflict, tuple(unique_fields), tuple(update_fields))
    compiled = _INSERTS.get((*key, connection.vendor))
    if compiled is None:
        compiled = _insert_sql(
            model, len(objs), on_conflict, unique_fields, update_fields, connection
        )
        if len(objs) <= _CACHED_ROWS:
            _INSERTS[(*key, connection.vendor)] = compiled
    sql, fields = compiled
    params = [
        field.get_db_prep_save(field.pre_save(obj, True), connection)
        for obj in objs
        for field in fields
    ]

    def take_keys(cursor: Any) -> None:
        for obj, (pk,) in zip(objs, cursor.fetchall(), strict=True):
            obj.pk = pk

    keyed = on_conflict is None and meta.pk not in fields
    _execute(connection, sql, params, take_keys if keyed else None)
    for obj in objs:
        obj._state.adding, obj._state.db = False, using


def _insert_sql(
    model: type[models.Model],
    rows: int,
    on_conflict: str | None,
    unique_fields: Sequence[str],
    update_fields: Sequence[str],
    connection: Any,
) -> tuple[str, list[Any]]:
    meta, quote = model._meta, connection.ops.quote_name
    fields = [
        field
        for field in meta.local_concrete_fields
        if not (field.primary_key and getattr(field, "db_returning", False))
    ]
    marks = f"({', '.join(['%s'] * len(fields))})"
    sql = (
        f"INSERT INTO {quote(meta.db_table)} ({', '.join(quote(f.column) for f in fields)}) "
        f"VALUES {', '.join([marks] * rows)}"
    )
    if on_conflict == "ignore":
        sql += " ON CONFLICT DO NOTHING"
    elif on_conflict == "update":
        unique = ", ".join(quote(meta.get_field(name).column) for name in unique_fields)
        updates = ", ".join(
            f"{quote(column)} = EXCLUDED.{quote(column)}"
            for column in (meta.get_field(name).column for name in update_fields)
        )
        sql += f" ON CONFLICT ({unique}) DO UPDATE SET {updates}"
    elif on_conflict is None:
        sql += f" RETURNING {quote(meta.pk.column)}"
    else:
        raise ValueError(f"on_conflict: None, 'ignore' or 'update', not {on_conflict!r}")
    return sql, fields


# --- units of work that do not wait for their writes ---------------------------------------


@dataclass
class _Pipeline:
    """A ``pipelined`` block on one connection: the psycopg pipeline, whether the statements
    run now may go on without their answers, and what to do with those answers."""

    pipeline: Any
    deferring: bool = False
    then: list[Callable[[], None]] = field(default_factory=list)
    checks: int = 0  # of the ``then``: those that may raise (the write did not do its part)

    def wait_unless_deferred(
        self, execute: Callable[..., Any], sql: str, params: Any, many: bool, context: Any
    ) -> Any:
        """A Django execute wrapper: every statement but a deferred one waits for its answer
        (and so for the answers of every statement before it), as outside a pipeline."""
        result = execute(sql, params, many, context)
        if not self.deferring:
            with context["connection"].wrap_database_errors:
                self.pipeline.sync()
        return result


_PIPELINE = "_cpcc_pipeline"


@contextlib.contextmanager
def pipelined(using: str = "default", *, commits: bool = False) -> Iterator[None]:
    """Run a unit of work (inside its transaction) with its ``deferred`` writes pipelined:
    sent to PostgreSQL at once, their answers read with the next statement that waits. When
    the block ends every answer is in, and what the deferred writes check (a row that was
    there to update, the keys of new rows) is done: a failure is raised there, inside the
    transaction, which then rolls back as it would have. On SQLite, or inside another
    ``pipelined``, it changes nothing.

    ``commits`` (``pipelined_transaction``): the block is all the work of the outermost
    transaction, which commits when it ends."""
    connection = connections[using]
    if connection.vendor != "postgresql" or getattr(connection, _PIPELINE, None) is not None:
        yield
        return
    connection.ensure_connection()
    pg = connection.connection
    # The transaction's BEGIN, when the block starts it, goes to the server with the unit's
    # first statements. psycopg would send its own BEGIN at the first statement and wait
    # for its answer, a round trip of its own: so the connection is put in autocommit
    # (psycopg then sends no BEGIN) and the block sends BEGIN itself, without waiting.
    # (Django's commit or rollback, if the block does not commit, ends that transaction.)
    begins = (
        commits and _outermost(connection) and pg.info.transaction_status == TransactionStatus.IDLE
    )
    with connection.wrap_database_errors:
        if begins:
            pg.autocommit = True
        try:
            with pg.pipeline() as pipeline:
                state = _Pipeline(pipeline)
                setattr(connection, _PIPELINE, state)
                try:
                    if begins:
                        pg.execute(_begin_statement(pg), prepare=False)
                    with connection.execute_wrapper(state.wait_unless_deferred):
                        yield
                    if commits and not state.checks and _outermost(connection):
                        # No check waits for the last writes' answers: the COMMIT goes with
                        # them and is answered in the same round trip. A write that fails
                        # makes the server skip it (the transaction rolls back) and is
                        # raised here, as it would have been; Django's commit then finds
                        # nothing left to send. A check that waits could still have to roll
                        # the writes back: then the COMMIT waits too.
                        pg.execute("COMMIT", prepare=False)
                finally:
                    setattr(connection, _PIPELINE, None)
        finally:
            if begins and not pg.closed and pg.info.transaction_status == TransactionStatus.IDLE:
                pg.autocommit = False  # as Django has it in a transaction
    for then in state.then:
        then()


def _begin_statement(pg: Any) -> str:
    """The BEGIN psycopg would send on this connection (its isolation level, as Django's
    settings chose it)."""
    parts = ["BEGIN"]
    if pg.isolation_level is not None:
        parts.append(f"ISOLATION LEVEL {IsolationLevel(pg.isolation_level).name.replace('_', ' ')}")
    if pg.read_only is not None:
        parts.append("READ ONLY" if pg.read_only else "READ WRITE")
    if pg.deferrable is not None:
        parts.append("DEFERRABLE" if pg.deferrable else "NOT DEFERRABLE")
    return " ".join(parts)


def _outermost(connection: Any) -> bool:
    """Whether the block runs directly in the outermost transaction, which is to commit."""
    return (
        connection.in_atomic_block
        and len(connection.atomic_blocks) == 1
        and not connection.savepoint_ids
        and not connection.needs_rollback
    )


@contextlib.contextmanager
def pipelined_transaction(using: str = "default") -> Iterator[None]:
    """A unit of work that is a transaction of its own: ``transaction.atomic()`` with
    ``pipelined`` inside. On PostgreSQL its BEGIN goes with its first statements, and its
    COMMIT with its last writes when no check waits for their answers (``save_fields`` of a
    row it holds, ``held``): two round trips a unit fewer; inside another transaction it is
    a savepoint, as ``atomic`` makes it, and commits nothing."""
    with transaction.atomic(using=using), pipelined(using, commits=True):
        yield


@contextlib.contextmanager
def deferred(using: str = "default") -> Iterator[None]:
    """Inside ``pipelined``: the writes of ``insert_rows``, ``save_fields`` and
    ``update_row`` (and any other statement whose answer nobody reads) do not wait for their
    answers. A new row's key is set when the ``pipelined`` block ends: nothing in the block
    may read it before. Outside ``pipelined`` it changes nothing."""
    state: _Pipeline | None = getattr(connections[using], _PIPELINE, None)
    if state is None or state.deferring:
        yield
        return
    state.deferring = True
    try:
        yield
    finally:
        state.deferring = False


def send_later(
    sql: str, params: Sequence[Any], *, using: str = "default"
) -> Callable[[], tuple[Any, ...] | None]:
    """Send a statement now and give back the function that reads its first row (None: no
    row): inside ``pipelined``, the statements sent before that read go to the server with
    it and their answers come back together, in one round trip (read it before the block
    ends); outside a pipeline the statement runs at once."""
    cursor = _sent(sql, params, using)

    def read() -> tuple[Any, ...] | None:
        try:
            row = cursor.fetchone()
        finally:
            cursor.close()
        return None if row is None else tuple(row)

    return read


def send_later_rows(
    sql: str, params: Sequence[Any], *, using: str = "default"
) -> Callable[[], list[tuple[Any, ...]]]:
    """``send_later``, whose reader gives every row."""
    cursor = _sent(sql, params, using)

    def read() -> list[tuple[Any, ...]]:
        try:
            return [tuple(row) for row in cursor.fetchall()]
        finally:
            cursor.close()

    return read


def _sent(sql: str, params: Sequence[Any], using: str) -> Any:
    with deferred(using):  # not waited for: the reader fetches its answer
        return _executed(connections[using], sql, params)


def _executed(connection: Any, sql: str, params: Sequence[Any]) -> Any:
    """A cursor that has run the statement (or sent it, deferred); closed if that failed.

    A deferred statement inside ``pipelined`` gets Django's cursor wrapper round a psycopg
    cursor of the connection the block holds, unless statements are logged (DEBUG, a test
    that counts them): ``connection.cursor()`` would check the connection, the thread and
    the time zone again for each statement (about 7 % of a unit of work's CPU)."""
    state: _Pipeline | None = getattr(connection, _PIPELINE, None)
    if state is None or not state.deferring or connection.queries_logged:
        cursor = connection.cursor()
    else:
        cursor = connection.make_cursor(connection.connection.cursor())
    try:
        cursor.execute(sql, params)
    except BaseException:
        cursor.close()
        raise
    return cursor


def _execute(
    connection: Any,
    sql: str,
    params: list[Any],
    answer: Callable[[Any], None] | None,
    *,
    checks: bool = False,
) -> None:
    """Run a write; ``answer(cursor)`` reads what it needs of its answer: at once, or, when
    the write is deferred, at the end of the ``pipelined`` block. ``checks``: ``answer`` may
    raise (the write did not do its part), which must roll back the unit's writes."""
    state: _Pipeline | None = getattr(connection, _PIPELINE, None)
    cursor = _executed(connection, sql, params)

    def read() -> None:
        try:
            if answer is not None:
                answer(cursor)
        finally:
            cursor.close()

    if state is None or not state.deferring or answer is None:
        read()  # at once
        return
    state.then.append(read)
    state.checks += checks
