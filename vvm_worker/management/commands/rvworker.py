"""``manage.py rvworker NAME``: the worker of one real vehicle (its queue and control loop)."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from fleet.models import Vehicle
from vvm_worker.dispatch import rv_queue
from vvm_worker.hosts import RVHost, set_host
from vvm_worker.management.commands._worker import ensure_broker, run_celery
from vvm_worker.planning import DEFAULT_PLANNER, PLANNER_NAMES


class Command(BaseCommand):
    help = "Run the worker of one real vehicle: its Celery queue and its control loop."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("name", help="the vehicle's name")
        parser.add_argument("--planner", choices=PLANNER_NAMES, default=DEFAULT_PLANNER)
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        try:
            vehicle = Vehicle.objects.get(name=options["name"])
        except Vehicle.DoesNotExist:
            known = ", ".join(Vehicle.objects.values_list("name", flat=True)) or "none"
            raise CommandError(
                f"no vehicle named {options['name']!r} (vehicles: {known})"
            ) from None
        ensure_broker()
        host = RVHost(vehicle, speed=settings.CPCC_SIM_SPEED, planner=options["planner"])
        set_host(host)
        host.start()
        self.stdout.write(f"rvworker {vehicle.name}: queue {rv_queue(vehicle.pk)}", ending="\n")
        self.stdout.flush()
        try:
            run_celery(
                queues=[rv_queue(vehicle.pk)], node=f"rv{vehicle.pk}", loglevel=options["loglevel"]
            )
        finally:
            host.stop()
            set_host(None)
