"""``manage.py gsworker NAME``: the worker of one ground station."""

from __future__ import annotations

from typing import Any

from django.core.management.base import BaseCommand, CommandError, CommandParser

from fleet.models import GroundStation
from vvm_worker.dispatch import SHARED_QUEUE, gs_queue
from vvm_worker.hosts import GSHost, set_host
from vvm_worker.management.commands._worker import ensure_broker, run_celery


class Command(BaseCommand):
    help = "Run the worker of one ground station: loads VVs, takes back those that end or wait."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("name", help="the ground station's name")
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        try:
            station = GroundStation.objects.get(name=options["name"])
        except GroundStation.DoesNotExist:
            known = ", ".join(GroundStation.objects.values_list("name", flat=True)) or "none"
            raise CommandError(
                f"no ground station named {options['name']!r} (ground stations: {known})"
            ) from None
        ensure_broker()
        host = GSHost(station)
        set_host(host)
        host.start()
        self.stdout.write(
            f"gsworker {station.name}: queues {gs_queue(station.pk)}, {SHARED_QUEUE}", ending="\n"
        )
        self.stdout.flush()
        try:
            run_celery(
                queues=[gs_queue(station.pk), SHARED_QUEUE],
                node=f"gs{station.pk}",
                loglevel=options["loglevel"],
            )
        finally:
            host.stop()
            set_host(None)
