"""``manage.py simulate SCENARIO.json``: run a scenario's whole fleet to its end in one process."""

from __future__ import annotations

import json
import logging
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

from django.conf import settings
from django.core.management import call_command
from django.core.management.base import BaseCommand, CommandError, CommandParser
from django.db import connections
from rich.console import Console
from rich.progress import BarColumn, TextColumn, TimeElapsedColumn
from rich.progress import Progress as Bar
from rich.table import Table

from vvm_worker.fresh_database import prepare_database
from vvm_worker.planning import DEFAULT_PLANNER, PLANNER_NAMES
from vvm_worker.scenario import ScenarioError, load_scenario
from vvm_worker.simulation import Progress, Simulation


def use_fresh_database(directory: Path) -> None:
    """Point the default database at a new SQLite file in ``directory`` with the platform's
    schema (a copy of the migrated template, vvm_worker/fresh_database.py)."""
    connections["default"].close()
    conf = connections.settings["default"]
    conf.update(
        {
            "ENGINE": "django.db.backends.sqlite3",
            "NAME": str(directory / "simulate.sqlite3"),
            "HOST": "",
            "PORT": "",
            "USER": "",
            "PASSWORD": "",
            # A throw-away file: what a power cut would lose does not matter, the fsyncs do.
            "OPTIONS": {"init_command": "PRAGMA synchronous=OFF; PRAGMA journal_mode=MEMORY;"},
            "CONN_MAX_AGE": 0,
        }
    )
    connections["default"] = connections.create_connection("default")
    prepare_database(directory / "simulate.sqlite3")


class Command(BaseCommand):
    help = (
        "Load a scenario into a fresh database (or the configured one with --keep), run the "
        "whole fleet to the end in one process and print progress and a summary."
    )

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("scenario", help="scenario file (JSON)")
        parser.add_argument(
            "--speed",
            type=float,
            default=None,
            help="time acceleration: 0 = discrete-event time, no sleeping (default: "
            "CPCC_SIM_SPEED, 1 = real time)",
        )
        parser.add_argument(
            "--planner",
            choices=PLANNER_NAMES,
            default=DEFAULT_PLANNER,
            help=f"route planner of every RV (default: {DEFAULT_PLANNER})",
        )
        parser.add_argument("--seed", type=int, default=1, help="seed of VVs and sensors")
        parser.add_argument(
            "--json", action="store_true", help="print the summary as JSON on the last line"
        )
        parser.add_argument(
            "--flights",
            action="store_true",
            help="add each RV's flights to the summary (count, flight time, distance)",
        )
        parser.add_argument(
            "--keep",
            action="store_true",
            help="use the configured database and keep the results there",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        speed = settings.CPCC_SIM_SPEED if options["speed"] is None else options["speed"]
        if options["verbosity"] < 2 and "CPCC_LOG_LEVEL" not in os.environ:
            # A simulation's flights and migrations are its summary; -v 2 shows each.
            logging.getLogger("cpcc").setLevel(logging.WARNING)
        if speed < 0:
            raise CommandError("--speed must be 0 (discrete-event) or positive")
        try:
            scenario = load_scenario(options["scenario"])
        except ScenarioError as exc:
            raise CommandError(f"scenario error: {exc}") from None
        with tempfile.TemporaryDirectory(prefix="cpcc-simulate-") as tmp:
            if options["keep"]:
                call_command("migrate", verbosity=0, interactive=False)
            else:
                use_fresh_database(Path(tmp))
            simulation = Simulation(
                scenario,
                planner=options["planner"],
                seed=options["seed"],
                speed=speed,
                logins=options["keep"],  # nobody logs in to a database deleted at the end
            )
            try:
                summary = self._run(simulation, flights=options["flights"])
            except ScenarioError as exc:
                raise CommandError(f"scenario error: {exc}") from None
            finally:
                connections["default"].close()
        pace = simulation.speed_line(summary)
        if options["json"]:
            # The JSON is the same on every run with the seed; the run's own speed is not.
            self.stderr.write(pace)
            self.stdout.write(json.dumps(summary, ensure_ascii=False))
        else:
            self._print_summary(summary)
            self.stdout.write(pace)

    def _run(self, simulation: Simulation, *, flights: bool) -> dict[str, Any]:
        if not sys.stderr.isatty():
            return simulation.run(flights=flights)
        # On stderr, so that stdout keeps only the summary.
        with Bar(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total} VVs ended"),
            TextColumn("· {task.fields[tasks]} tasks done · t = {task.fields[sim_s]:.1f} s"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            transient=False,
        ) as bar:
            job = bar.add_task(
                simulation.scenario.name, total=simulation.vv_count, tasks=0, sim_s=0.0
            )

            def report(p: Progress) -> None:
                bar.update(
                    job,
                    total=p.vvs_total,
                    completed=p.vvs_ended,
                    tasks=p.tasks_done,
                    sim_s=p.time_s,
                )

            return simulation.run(progress=report, flights=flights)

    def _print_summary(self, summary: dict[str, Any]) -> None:
        console = Console(file=self.stdout._out, highlight=False)  # type: ignore[attr-defined]
        vvs = Table(title=f"Virtual vehicles (planner {summary['planner']})")
        for column in ("VV", "customer", "status", "tasks", "finished at (s)", "error"):
            vvs.add_column(column)
        for vv in summary["vvs"]:
            finished = "" if vv["finished_s"] is None else f"{vv['finished_s']:.1f}"
            vvs.add_row(
                vv["name"],
                vv["customer"],
                vv["status"],
                str(vv["tasks_done"]),
                finished,
                vv["error"] or "",
            )
        console.print(vvs)
        rvs = Table(title="Vehicles")
        for column in ("RV", "tasks", "distance (m)", "flight (s)"):
            rvs.add_column(column)
        for rv in summary["vehicles"]:
            rvs.add_row(
                rv["name"],
                str(rv["tasks_done"]),
                f"{rv['distance_m']:.0f}",
                f"{rv['flight_s']:.0f}",
            )
        console.print(rvs)
        console.print(
            f"{len(summary['migrations'])} migrations; makespan {summary['makespan_s']:.1f} s"
        )
        latency = summary["latency"]
        if latency["tasks"]:
            console.print(
                f"task latency (request to reading) over {latency['tasks']} tasks: "
                f"mean {latency['mean_s']:.1f} s, p95 {latency['p95_s']:.1f} s, "
                f"max {latency['max_s']:.1f} s"
            )
        if "service_levels" in summary:
            levels = summary["service_levels"]
            console.print(service_level_table(levels["customers"]))
            console.print(service_level_table(levels["classes"], "Service levels per class"))
        if "flights" in summary:
            flights = Table(title="Flights")
            for column in ("RV", "flights", "flight time (s)", "distance (m)"):
                flights.add_column(column)
            for row in summary["flights"]:
                flights.add_row(
                    row["vehicle"],
                    str(row["flights"]),
                    f"{row['flight_s']:.0f}",
                    f"{row['distance_m']:.0f}",
                )
            console.print(flights)


def service_level_table(rows: list[dict[str, Any]], title: str = "Service levels") -> Table:
    """Figures per customer (or class) and class: ``LevelStats.as_dict`` rows as a table."""
    table = Table(title=title)
    for column in (
        "class",
        "customer",
        "target p95 (s)",
        "requests",
        "median (s)",
        "p95 (s)",
        "within target",
        "meets target",
    ):
        table.add_column(column)
    for row in rows:
        target = row["target_p95_s"]
        within = row["within_target"]
        meets = row["meets_target"]
        table.add_row(
            row["service_class"],
            row["customer"],
            "" if target is None else f"{target:.0f}",
            str(row["requests"]),
            f"{row['median_s']:.1f}",
            f"{row['p95_s']:.1f}",
            "" if within is None else f"{within:.1%}",
            "" if meets is None else ("yes" if meets else "no"),
        )
    return table
