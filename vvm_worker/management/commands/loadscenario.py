"""``manage.py loadscenario SCENARIO.json``: put a scenario into the configured database."""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from vvm_worker.platform import platform_vvm
from vvm_worker.scenario import ScenarioError, load_scenario
from vvm_worker.services.scenarios import scenario_apply, scenario_submit_all


class Command(BaseCommand):
    help = (
        "Put a scenario's SDC additions, ground stations, vehicles (with their pilots), staff "
        "(in their groups) and customers (with a login user each, its owner, and the users the "
        "scenario names, with their roles; passwords from CPCC_SCENARIO_PASSWORD or generated) "
        "into the configured database (idempotent) and submit its VVs."
    )

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("scenario", help="scenario file (JSON)")
        parser.add_argument(
            "--no-vvs", action="store_true", help="load the fleet and customers only"
        )

    def handle(self, *args: Any, **options: Any) -> None:
        try:
            scenario = load_scenario(options["scenario"])
            loaded = scenario_apply(
                scenario=scenario, password=settings.CPCC_SCENARIO_PASSWORD or None
            )
        except ScenarioError as exc:
            raise CommandError(f"scenario error: {exc}") from None
        self.stdout.write(
            f"Loaded {scenario.name!r}: {len(loaded.ground_stations)} ground station(s), "
            f"{len(loaded.vehicles)} vehicle(s), {len(loaded.customers)} customer(s)."
        )
        for username, password in loaded.logins:
            shown = password if password is not None else "(unchanged)"
            label = loaded.labels.get(username)
            if label is not None and username in loaded.staff:
                label = f"staff: {label}"
            self.stdout.write(f"  login {username} / {shown}" + (f"  ({label})" if label else ""))
        if options["no_vvs"]:
            return
        # Queued only: the ground-station workers admit them within each customer's quota.
        vvs = scenario_submit_all(scenario=scenario, loaded=loaded, vvm=platform_vvm(), admit=False)
        self.stdout.write(f"Submitted {len(vvs)} VV(s); they wait queued for the workers.")
