"""``manage.py gsworker NAME``: the worker of one ground station."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandParser

from fleet.models import GroundStation
from vvm_worker.dispatch import SHARED_QUEUE, gs_queue
from vvm_worker.hosts import GSHost
from vvm_worker.management.commands._worker import host_named, prepare_isolates, serve


class Command(BaseCommand):
    help = "Run the worker of one ground station: loads VVs, takes back those that end or wait."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("name", help="the ground station's name")
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        station = host_named(GroundStation, options["name"], "ground station")
        prepare_isolates(settings.CPCC_GS_ISOLATE_POOL)  # every new VV starts here
        serve(
            self,
            GSHost(station),
            # (webhooks and e-mails: manage.py notifyworker, in threads of its own)
            queues=[gs_queue(station.pk), SHARED_QUEUE],
            node=f"gs{station.pk}",
            loglevel=options["loglevel"],
        )
