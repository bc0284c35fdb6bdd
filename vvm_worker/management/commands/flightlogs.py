"""``manage.py flightlogs --prune``: delete the flight logs older than ``CPCC_FLIGHT_LOG_DAYS``
(each RV worker also does it daily)."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from vvm_worker.services.flight_logs import flight_logs_prune


class Command(BaseCommand):
    help = (
        "Flight logs (.tlog): --prune deletes those of flights ended over CPCC_FLIGHT_LOG_DAYS ago."
    )

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "--prune",
            action="store_true",
            help="delete the logs of flights that ended more than CPCC_FLIGHT_LOG_DAYS ago",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        if not options["prune"]:
            raise CommandError("nothing to do: give --prune")
        deleted = flight_logs_prune()
        self.stdout.write(
            f"{deleted} flight log(s) deleted (older than {settings.CPCC_FLIGHT_LOG_DAYS:g} days)"
        )
