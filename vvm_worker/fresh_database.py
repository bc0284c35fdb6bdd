"""A new SQLite database with the platform's schema, in milliseconds: a copy of a database
migrated once per version of the migrations, kept under VAR_DIR/schema/ (migrating takes a
second or two, copying a file a few milliseconds). A dry run's copy of the fleet and
``manage.py simulate`` start from one."""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import sqlite3
from pathlib import Path

from django.apps import apps
from django.conf import settings
from django.core.management import call_command
from django.db import connection


def prepare_database(path: Path) -> None:
    """Give the new default database at ``path`` (not opened yet) the platform's schema and
    what the migrations put in it (the default SDC): a copy of the template of these
    migrations, made now by migrating when there is none yet."""
    # A throw-away file: what a power cut would lose does not matter, the fsyncs do.
    connection.settings_dict["OPTIONS"]["init_command"] = (
        "PRAGMA journal_mode=MEMORY; PRAGMA synchronous=OFF;"
    )
    template = Path(settings.VAR_DIR) / "schema" / f"schema-{_migrations_digest()}.sqlite3"
    with contextlib.suppress(FileNotFoundError):  # none yet (or another version's went)
        shutil.copyfile(template, path)
        return
    call_command("migrate", verbosity=0, interactive=False)
    connection.close()
    template.parent.mkdir(parents=True, exist_ok=True)
    # Several processes may make the template at once: each writes a file of its own and puts
    # it in place in one step (the last one stays; they are the same).
    partial = template.with_name(f"{template.name}.{os.getpid()}.part")
    with (
        contextlib.closing(sqlite3.connect(path)) as source,
        contextlib.closing(sqlite3.connect(partial)) as copy,
    ):
        source.backup(copy)
    partial.replace(template)
    for old in template.parent.glob("schema-*.sqlite3"):  # of migrations that are gone
        if old != template:
            old.unlink(missing_ok=True)


def _migrations_digest() -> str:
    """A digest of every installed app's migration files: a new migration, a new template."""
    digest = hashlib.sha256()
    for config in sorted(apps.get_app_configs(), key=lambda c: c.label):
        for file in sorted((Path(config.path) / "migrations").glob("*.py")):
            digest.update(f"{config.label}/{file.name}\n".encode())
            digest.update(file.read_bytes())
    return digest.hexdigest()[:16]
