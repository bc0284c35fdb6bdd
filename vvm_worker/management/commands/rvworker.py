"""``manage.py rvworker NAME [NAME ...]``: the worker of one or more real vehicles in one
process (their Celery queues and control loops, one host thread and one V8 runtime)."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from fleet.models import Vehicle
from vvm_worker.dispatch import rv_queue
from vvm_worker.hosts import CannotFly, RVHost
from vvm_worker.management.commands._worker import hosts_named, prepare_isolates, serve
from vvm_worker.planning import DEFAULT_PLANNER, PLANNER_NAMES

# Isolates kept prepared for each vehicle hosted (about 1.7 MB each), up to MAX_PREPARED.
ISOLATES_PER_VEHICLE = 2
MAX_PREPARED = 32


class Command(BaseCommand):
    help = (
        "Run the worker of one or more real vehicles in one process: their Celery queues "
        "and control loops."
    )

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "names",
            nargs="+",
            metavar="NAME",
            help="the vehicles' names (one on a vehicle's own computer, several on a server)",
        )
        parser.add_argument("--planner", choices=PLANNER_NAMES, default=DEFAULT_PLANNER)
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        vehicles: list[Vehicle] = hosts_named(Vehicle, options["names"], "vehicle")
        try:
            host = RVHost(vehicles, speed=settings.CPCC_SIM_SPEED, planner=options["planner"])
        except CannotFly as exc:
            raise CommandError(str(exc)) from None
        ids = [vehicle.pk for vehicle in vehicles]
        # A VV arriving from another process needs a new context: two ready per vehicle.
        prepare_isolates(min(ISOLATES_PER_VEHICLE * len(ids), MAX_PREPARED))
        serve(
            self,
            host,
            queues=[rv_queue(pk) for pk in ids],
            # One vehicle's worker is rv<id>, as ever; a group's is named by its first.
            node=f"rv{ids[0]}" if len(ids) == 1 else f"rv{ids[0]}+{len(ids) - 1}",
            loglevel=options["loglevel"],
        )
