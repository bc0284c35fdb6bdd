"""SQL written by hand has one home: the store (vvm_worker/services/store/), resting on
cpcc_site/prepared.py. A service, view or command that opens a cursor, runs raw SQL or adds
it to a queryset fails here with where it does so (the ORM, and the store by intent, are the
ways in)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
APPS = ("accounts", "fleet", "missions", "vvm_worker", "cpcc_site", "cpcc_client")
# Where SQL may be written by hand: the store, the mechanics it rests on, and the outage
# probe's "SELECT 1".
HOMES = ("vvm_worker/services/store/", "cpcc_site/prepared.py", "cpcc_site/database.py")
# Calls that run or embed SQL written by hand: a cursor, Manager.raw, QuerySet.extra, RawSQL.
BY_HAND_METHODS = {"cursor", "raw", "extra"}
BY_HAND_NAMES = {"RawSQL"}


def sql_by_hand(source: str) -> list[tuple[int, str]]:
    """(line, what) of each call in ``source`` that runs or embeds SQL written by hand."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        if isinstance(func, ast.Attribute) and func.attr in BY_HAND_METHODS:
            found.append((node.lineno, f".{func.attr}()"))
        elif isinstance(func, ast.Name) and func.id in BY_HAND_NAMES:
            found.append((node.lineno, f"{func.id}()"))
    return sorted(found)


def modules() -> list[Path]:
    return sorted(
        path
        for app in APPS
        for path in (ROOT / app).rglob("*.py")
        if "migrations" not in path.parts
    )


@pytest.mark.backend_independent("reads the project's source: no database is asked")
def test_only_the_store_writes_sql_by_hand() -> None:
    outside = [
        f"{path.relative_to(ROOT)}:{line}: {what}"
        for path in modules()
        if not str(path.relative_to(ROOT)).startswith(HOMES)
        for line, what in sql_by_hand(path.read_text())
    ]
    assert outside == [], (
        "SQL written by hand outside the store (move it to vvm_worker/services/store/ and "
        f"call it by intent): {outside}"
    )


@pytest.mark.backend_independent("parses a snippet: no database is asked")
def test_the_check_sees_each_way_of_writing_sql_by_hand() -> None:
    source = (
        "with connection.cursor() as c:\n    c.execute('UPDATE t SET a = 1')\n"
        "Task.objects.raw('SELECT * FROM t')\n"
        "Task.objects.extra(where=['a = 1'])\n"
        "Task.objects.annotate(n=RawSQL('SELECT 1', []))\n"
        "Task.objects.filter(a=1).update(b=2)\n"
    )
    assert sql_by_hand(source) == [
        (1, ".cursor()"),
        (3, ".raw()"),
        (4, ".extra()"),
        (5, "RawSQL()"),
    ]
