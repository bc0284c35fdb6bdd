"""Reads made again and again (at every step of a VV, at every API request), compiled once.

Django compiles a queryset's SQL each time it runs: for a VV's row with its customer and hosts
(about 90 columns over four tables) that is half a millisecond, five times the time the
database takes to answer. A ``PreparedRead`` compiles its queryset once per database and
runs the same SQL again with new parameters, building the model instances (and the related
ones of ``select_related``) exactly as a queryset would.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Generic, TypeVar

from django.db import DatabaseError, connections, models
from django.db.models.query import get_related_populators

M = TypeVar("M", bound=models.Model)


class PreparedRead(Generic[M]):
    """``build(*keys)`` is a queryset that selects rows by the values ``keys`` (a primary key,
    say, and the customer the row must belong to); ``first(*keys)`` runs it for other values.
    ``samples`` names the model's field of each key (``pk`` or a field's name or attname) and a
    value of it that the query holds nowhere else (to find its place among the parameters).
    The queryset may use ``select_related`` and ``select_for_update`` (then ``first`` must run
    in a transaction, as the queryset would). Safe to share between threads."""

    def __init__(
        self, build: Callable[..., models.QuerySet[M]], *, samples: Sequence[tuple[str, Any]]
    ) -> None:
        self.build = build
        self.samples = list(samples)
        self._compiled: dict[tuple[str, str], tuple[Any, str, list[Any], list[int]]] = {}

    def first(self, *keys: Any, using: str = "default") -> M | None:
        connection = connections[using]
        compiled = self._compiled.get((using, connection.vendor))
        if compiled is None:
            compiled = self._compile(using)
            self._compiled[(using, connection.vendor)] = compiled
        compiler, sql, params, places = compiled
        params = [*params]
        for (name, _), at, key in zip(self.samples, places, keys, strict=True):
            params[at] = self._field(compiler.query.model, name).get_db_prep_value(key, connection)
        with connection.cursor() as cursor:
            cursor.execute(sql, params)
            row = cursor.fetchone()
        if row is None:
            return None
        select, klass_info = compiler.select, compiler.klass_info
        converters = compiler.get_converters([column for column, _, _ in select])
        if converters:
            (row,) = compiler.apply_converters([row], converters)
        fields = klass_info["select_fields"]
        start, end = fields[0], fields[-1] + 1
        names = [column.target.attname for column, _, _ in select[start:end]]
        obj: M = klass_info["model"].from_db(using, names, row[start:end])
        for populator in get_related_populators(klass_info, select, using):
            populator.populate(row, obj)
        return obj

    @staticmethod
    def _field(model: type[models.Model], name: str) -> Any:
        return model._meta.pk if name == "pk" else model._meta.get_field(name)

    def _compile(self, using: str) -> tuple[Any, str, list[Any], list[int]]:
        connection = connections[using]
        queryset = self.build(*(value for _, value in self.samples))
        compiler = queryset.query.get_compiler(using=using)
        sql, params = compiler.as_sql()
        at = []
        for name, value in self.samples:
            marker = self._field(queryset.model, name).get_db_prep_value(value, connection)
            places = [i for i, param in enumerate(params) if param == marker]
            if len(places) != 1:
                raise ValueError(f"the key {name} must appear once among the parameters: {places}")
            at.append(places[0])
        return compiler, sql, list(params), at


_UPDATES: dict[tuple[type[models.Model], tuple[str, ...], str], tuple[str, list[Any]]] = {}


def save_fields(obj: models.Model, fields: Sequence[str], *, using: str = "default") -> None:
    """``obj.save(update_fields=fields)`` for a model without save signals that anyone
    listens to, with its SQL compiled once per model and set of fields: one ``UPDATE`` by the
    primary key. Fields that set themselves (``auto_now``) do so as in ``save``. Raises
    ``DatabaseError``, as ``save`` does, if the row is not there."""
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
    with connection.cursor() as cursor:
        cursor.execute(sql, params)
        if cursor.rowcount != 1:
            raise DatabaseError(f"{model.__name__} {obj.pk}: no row to update")
