"""``manage.py rvworker NAME [NAME ...] [--station GS]``: the worker of one or more real
vehicles in one process (their Celery queues and control loops, one host thread and one V8
runtime), and with ``--station`` of the ground station they start from too."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from fleet.models import GroundStation, Vehicle
from vvm_worker.dispatch import SHARED_QUEUE, gs_queue, rv_queue
from vvm_worker.hosts import CannotFly, RVHost
from vvm_worker.management.commands._worker import (
    host_named,
    hosts_named,
    prepare_isolates,
    serve,
)
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
        parser.add_argument(
            "--station",
            metavar="GS",
            help=(
                "also host this ground station (instead of a gsworker of its own): its VVs "
                "go to these vehicles with their warm contexts, without a message"
            ),
        )
        parser.add_argument("--planner", choices=PLANNER_NAMES, default=DEFAULT_PLANNER)
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        vehicles: list[Vehicle] = hosts_named(Vehicle, options["names"], "vehicle")
        station = None
        if options["station"] is not None:
            station = host_named(GroundStation, options["station"], "ground station")
        try:
            host = RVHost(
                vehicles,
                speed=settings.CPCC_SIM_SPEED,
                planner=options["planner"],
                station=station,
            )
        except CannotFly as exc:
            raise CommandError(str(exc)) from None
        ids = [vehicle.pk for vehicle in vehicles]
        queues = [rv_queue(pk) for pk in ids]
        # A VV arriving from another process needs a new context: two ready per vehicle.
        isolates = min(ISOLATES_PER_VEHICLE * len(ids), MAX_PREPARED)
        if station is not None:
            # Every new VV starts on the station, and the station's messages come here: its
            # own queue and admission (as a gsworker's).
            isolates += settings.CPCC_GS_ISOLATE_POOL
            queues += [gs_queue(station.pk), SHARED_QUEUE]
        prepare_isolates(isolates)
        serve(
            self,
            host,
            queues=queues,
            # One vehicle's worker is rv<id>, as ever; a group's is named by its first.
            node=f"rv{ids[0]}" if len(ids) == 1 else f"rv{ids[0]}+{len(ids) - 1}",
            loglevel=options["loglevel"],
        )
