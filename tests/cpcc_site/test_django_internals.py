"""The parts of Django that cpcc_site/prepared.py uses without Django promising them: a Django
release that changes one fails here, by name, before a prepared read builds wrong objects."""

from __future__ import annotations

import importlib
import inspect

import pytest
from django.db import connection, transaction

from cpcc_site.prepared import DJANGO_INTERNALS
from missions.models import VirtualVehicle

# Those named by their module's path; the others are attributes, checked on real objects below.
CALLABLES = {path: text for path, text in DJANGO_INTERNALS.items() if path.startswith("django.")}


def resolve(path: str) -> object:
    """The object at a dotted path: a module's attribute, or a class's."""
    parts = path.split(".")
    for split in range(len(parts) - 1, 0, -1):
        try:
            found: object = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        for name in parts[split:]:
            found = getattr(found, name)
        return found
    raise ImportError(path)


@pytest.mark.backend_independent("signatures of Django's code: no database is asked")
@pytest.mark.parametrize("path", sorted(CALLABLES))
def test_every_internal_callable_is_there_with_its_signature(path: str) -> None:
    assert str(inspect.signature(resolve(path))) == CALLABLES[path], (
        f"Django changed {path}: cpcc_site/prepared.py calls it as {CALLABLES[path]}"
    )


def test_a_compiled_read_has_the_parts_the_prepared_reads_take(customer_a, db) -> None:
    queryset = VirtualVehicle.objects.select_related("customer", "host_rv").filter(pk=None)
    compiler = queryset.query.get_compiler(using="default")
    sql, _ = compiler.as_sql()
    assert sql.startswith("SELECT")
    # select: (column, sql, alias) triples whose columns name their field.
    assert all(len(entry) == 3 for entry in compiler.select)
    info = compiler.klass_info
    assert {"model", "select_fields", "related_klass_infos"} <= set(info)
    assert info["model"] is VirtualVehicle
    names = [compiler.select[i][0].target.attname for i in info["select_fields"]]
    assert names == [field.attname for field in VirtualVehicle._meta.local_concrete_fields]
    assert {related["model"].__name__ for related in info["related_klass_infos"]} == {
        "Customer",
        "Vehicle",
    }
    assert isinstance(compiler.annotation_col_map, dict)
    assert isinstance(compiler.get_converters([c for c, _, _ in compiler.select]), dict)
    populators = resolve("django.db.models.query.get_related_populators")(
        info, compiler.select, "default"
    )
    assert len(populators) == 2 and all(hasattr(p, "populate") for p in populators)
    built = VirtualVehicle()
    assert built._state.adding is True and built._state.db is None
    read = type(customer_a).objects.get(pk=customer_a.pk)
    assert read._state.adding is False and read._state.db == "default"


def test_a_connection_has_the_parts_the_units_of_work_take(db) -> None:
    with transaction.atomic():
        assert connection.in_atomic_block is True
        assert isinstance(connection.atomic_blocks, list) and connection.atomic_blocks
        assert isinstance(connection.savepoint_ids, list)
        assert connection.needs_rollback is False
    connection.ensure_connection()
    assert isinstance(connection.queries_logged, bool)
    with connection.wrap_database_errors:
        pass
