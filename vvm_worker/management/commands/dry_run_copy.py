"""``manage.py dry_run_copy FOLDER``: the simulated copy of the fleet a dry run flies, in a
process of its own (``vvm_worker.services.dry_run`` starts it; not a command for people).

FOLDER holds ``request.json`` (what ``vv_dry_run_for_user`` sends); the default database must
be a new SQLite file (``DATABASE_URL``), which gets the platform's schema. The report goes to
FOLDER/report.json, with the CPU seconds this process used (``cpu_s``: what the dry run
counts against the customer's budget).
"""

from __future__ import annotations

import json
import resource
from pathlib import Path
from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from vvm_worker.dry_run_copy import run_copy
from vvm_worker.fresh_database import prepare_database


class Command(BaseCommand):
    help = (
        "Internal: run a dry run's simulated copy of the fleet (FOLDER/request.json) on a new "
        "SQLite database and write FOLDER/report.json."
    )
    requires_system_checks: list[str] = []  # a process per dry run: start fast

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("folder", help="where request.json is and report.json goes")

    def handle(self, *args: Any, **options: Any) -> None:
        folder = Path(options["folder"])
        database = settings.DATABASES["default"]
        if not database["ENGINE"].endswith("sqlite3") or Path(database["NAME"]).exists():
            # Never the platform's own database: the copy writes freely into its own.
            raise CommandError("DATABASE_URL must name a new SQLite file")
        request = json.loads((folder / "request.json").read_text(encoding="utf-8"))
        prepare_database(Path(database["NAME"]))
        report = run_copy(request)
        partial = folder / "report.json.part"
        used = resource.getrusage(resource.RUSAGE_SELF)
        written = {**report.to_json(), "cpu_s": round(used.ru_utime + used.ru_stime, 3)}
        partial.write_text(json.dumps(written), encoding="utf-8")
        partial.replace(folder / "report.json")
