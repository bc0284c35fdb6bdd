"""``manage.py notifyworker [NAME]``: the worker that tells customers what happened to their VVs.

It serves the ``notify`` queue alone, in threads of its own (``CPCC_NOTIFY_THREADS``): the
e-mails and the webhook POSTs. No station's or vehicle's worker waits on a customer's
receiver, and one customer's webhooks hold at most ``CPCC_NOTIFY_PER_CUSTOMER`` of the
threads at once, so a slow or hostile receiver delays only its own customer's notifications.
Run one (or more, each with a NAME of its own) beside the ground stations' workers.
"""

from __future__ import annotations

import signal
from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandParser

from vvm_worker.delivery import NOTIFY_QUEUE
from vvm_worker.management.commands._worker import (
    ensure_broker,
    run_celery,
    stop_celery,
    stop_now,
)


class Command(BaseCommand):
    help = "Run the worker that sends the customers' webhooks and e-mails (the notify queue)."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument(
            "name", nargs="?", default="notify", help="this worker's name, when several run"
        )
        parser.add_argument(
            "--threads",
            type=int,
            default=None,
            help="threads that deliver at once (default: CPCC_NOTIFY_THREADS)",
        )
        parser.add_argument("--loglevel", default="WARNING")

    def handle(self, *args: Any, **options: Any) -> None:
        threads = options["threads"] or settings.CPCC_NOTIFY_THREADS
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, stop_now)
        ensure_broker()
        self.stdout.write(
            f"notifyworker {options['name']}: queue {NOTIFY_QUEUE}, {threads} threads, "
            f"{settings.CPCC_NOTIFY_PER_CUSTOMER} a customer"
        )
        self.stdout.flush()
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, stop_celery)
        run_celery(
            queues=[NOTIFY_QUEUE],
            node=f"notify-{options['name']}",
            loglevel=options["loglevel"],
            threads=threads,
        )
