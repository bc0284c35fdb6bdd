"""``manage.py rvworker NAME``: the worker of one real vehicle (its queue and control loop)."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from fleet.mavlink.errors import MavlinkError
from fleet.models import Vehicle
from vvm_worker.dispatch import rv_queue
from vvm_worker.hosts import RVHost
from vvm_worker.management.commands._worker import host_named, serve
from vvm_worker.planning import DEFAULT_PLANNER, PLANNER_NAMES


class Command(BaseCommand):
    help = "Run the worker of one real vehicle: its Celery queue and its control loop."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("name", help="the vehicle's name")
        parser.add_argument("--planner", choices=PLANNER_NAMES, default=DEFAULT_PLANNER)
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        vehicle = host_named(Vehicle, options["name"], "vehicle")
        try:
            host = RVHost(vehicle, speed=settings.CPCC_SIM_SPEED, planner=options["planner"])
        except (MavlinkError, ValueError) as exc:
            where = f" at {vehicle.driver_url}" if vehicle.driver_url else ""
            raise CommandError(f"{vehicle.name}: cannot fly its vehicle{where}: {exc}") from None
        serve(
            self,
            host,
            queues=[rv_queue(vehicle.pk)],
            node=f"rv{vehicle.pk}",
            loglevel=options["loglevel"],
        )
