"""``python -m bench.service_levels`` (``make bench-service-levels``): does a premium class keep
its 30 s target on a busy fleet when a standard customer floods it (issue 28)?

One scenario, generated here, run twice in this process on discrete-event time (a fresh SQLite
database each, the same seed): with the service classes, and with them removed (everyone
weight 1, no admission hold). A grid of ``--rows`` x ``--cols`` RVs (200 m cells, 10 m/s);
three customers submit one-task VVs (the original demo5 program) anywhere on the grid:

- "Premium" (class premium: p95 30 s, weight ``--weight``), Poisson arrivals;
- "Standard" (class standard: p95 120 s, weight 1), Poisson arrivals;
- "Flood" (class standard too), ``--flood`` VVs submitted at once at ``--flood-at`` s, and
  again ``--floods`` times every ``--flood-every`` s.

By default 465 one-task VVs in about 30 minutes: a task every 15 s per RV on average, where
an RV needs some 10 s for a lone task (100 m and a climb at 10 m/s), so the fleet keeps up,
but not by much; each flood puts 15 more tasks on every RV at once, which take it a minute or
two to clear. Prints and writes (``--out``, JSON) per class
the requests read, median and p95 latency (request to reading) and the share within target,
for both runs, as the platform's report computes it (``service_levels_report`` on each run's
database: what the admin page and ``GET /api/v1/service-levels/`` show).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

PREMIUM = {"name": "premium", "p95_s": 30.0}
STANDARD = {"name": "standard", "p95_s": 120.0, "weight": 1.0}
CELL_M = 200.0


def scenario(args: argparse.Namespace, *, classes: bool) -> dict[str, Any]:
    """The benchmark's scenario; without ``classes`` the same one with no customer in a class."""
    from fleet.geo import Position
    from vvm_worker.scenario_gen import ONE_TASK, grid_box, grid_scenario, poisson_tasks

    box = grid_box(rows=args.rows, cols=args.cols, cell_m=CELL_M)

    def one_task(customer: str, name: str, at_s: float, p: Position) -> dict[str, Any]:
        return {
            "customer": customer,
            "name": name,
            "source": ONE_TASK % {"lat": p.lat, "lng": p.lng, "alt": p.alt},
            "submit_at_s": at_s,
        }

    vvs = []
    streams = (("Premium", args.premium_gap, 1), ("Standard", args.standard_gap, 2))
    for customer, gap, seed in streams:
        count = int(args.duration / gap)
        arrivals = poisson_tasks(mean_gap_s=gap, seed=args.seed * 10 + seed, count=count, box=box)
        vvs += [
            one_task(customer, f"{customer} {k + 1:03d}", at_s, p)
            for k, (at_s, p) in enumerate(arrivals)
        ]
    rng = random.Random(args.seed * 10 + 3)
    for wave in range(args.floods):
        at_s = args.flood_at + wave * args.flood_every
        for k in range(args.flood):
            p = Position(
                rng.uniform(box["south"], box["north"]),
                rng.uniform(box["west"], box["east"]),
                rng.uniform(5.0, 55.0),
            )
            vvs.append(one_task("Flood", f"Flood {wave + 1}.{k + 1:03d}", at_s, p))
    data = grid_scenario(
        rows=args.rows,
        cols=args.cols,
        cell_m=CELL_M,
        max_speed_mps=10.0,
        customers=3,
        max_parallel_vvs=len(vvs),
        vvs=vvs,
        name=f"service levels: {len(vvs)} VVs on {args.rows}x{args.cols} RVs",
    )
    for customer, (name, service_class) in zip(
        data["customers"], class_of(args).items(), strict=True
    ):
        customer["name"] = name
        if classes:
            customer["service_class"] = service_class
    return data


def class_of(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """Each customer's class."""
    premium = {**PREMIUM, "weight": args.weight}
    return {"Premium": premium, "Standard": STANDARD, "Flood": STANDARD}


def run(
    data: dict[str, Any], directory: Path, seed: int, classes: dict[str, dict[str, Any]]
) -> dict[str, Any]:
    """Run one scenario on a fresh database in ``directory``: the report per class and per
    customer, how many VVs finished, the simulated and the wall time. A run without classes
    is reported with its customers put in ``classes`` once it has ended (the report counts a
    customer in the class it has now), so that its figures are held against the same
    targets."""
    from accounts.models import Customer
    from vvm_worker.management.commands.simulate import use_fresh_database
    from vvm_worker.scenario import parse_scenario
    from vvm_worker.services.customers import customer_class_set, service_class_save
    from vvm_worker.services.service_levels import service_levels_report
    from vvm_worker.simulation import Simulation

    directory.mkdir(parents=True)
    use_fresh_database(directory)
    simulation = Simulation(parse_scenario(data, base_dir=ROOT), seed=seed, logins=False)
    started = time.perf_counter()
    summary = simulation.run()
    wall = time.perf_counter() - started
    for customer in Customer.objects.filter(service_class__isnull=True):
        spec = classes[customer.name]
        service_class = service_class_save(
            name=spec["name"], p95_s=spec["p95_s"], weight=spec["weight"]
        )
        customer_class_set(customer=customer, service_class=service_class, vvm=simulation.vvm)
    # The platform's report on this run's database (the admin page's and the API's figures).
    return {
        "classes": [s.as_dict() for s in service_levels_report(by_customer=False)],
        "customers": [s.as_dict() for s in service_levels_report()],
        "vvs": len(summary["vvs"]),
        "finished": sum(1 for vv in summary["vvs"] if vv["status"] == "finished"),
        "makespan_s": summary["makespan_s"],
        "wall_s": round(wall, 1),
    }


def table(result: dict[str, Any], key: str = "customers") -> list[str]:
    lines = [
        "| class | customer | target | requests | median | p95 | within target | meets |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in result[key]:
        target = "—" if row["target_p95_s"] is None else f"{row['target_p95_s']:g} s"
        within = "—" if row["within_target"] is None else f"{row['within_target']:.1%}"
        meets = {None: "—", True: "yes", False: "no"}[row["meets_target"]]
        lines.append(
            f"| {row['service_class']} | {row['customer']} | {target} | {row['requests']} | "
            f"{row['median_s']:.1f} s | {row['p95_s']:.1f} s | {within} | {meets} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rows", type=int, default=2)
    parser.add_argument("--cols", type=int, default=2)
    parser.add_argument("--weight", type=float, default=10.0, help="the premium class's weight")
    parser.add_argument("--premium-gap", type=float, default=30.0, help="mean s between VVs")
    parser.add_argument("--standard-gap", type=float, default=8.0, help="mean s between VVs")
    parser.add_argument("--flood", type=int, default=60, help="VVs of one flood")
    parser.add_argument("--floods", type=int, default=3)
    parser.add_argument("--flood-at", type=float, default=300.0)
    parser.add_argument("--flood-every", type=float, default=600.0)
    parser.add_argument("--duration", type=float, default=1800.0, help="s of Poisson arrivals")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", default="var/bench/service_levels.json")
    parser.add_argument(
        "--keep",
        action="store_true",
        help="keep the runs' SQLite databases (printed) to look at them in the admin",
    )
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="cpcc-bench-levels-"))
    os.environ.update(
        CPCC_VAR_DIR=str(tmp),
        CPCC_MEDIA_ROOT=str(tmp / "media"),
        DJANGO_SETTINGS_MODULE="cpcc_site.settings",
        CPCC_LOG_LEVEL=os.environ.get("CPCC_LOG_LEVEL", "WARNING"),
    )
    os.chdir(ROOT)
    import django

    django.setup()

    machine = (
        f"{platform.processor() or platform.machine()} · {os.cpu_count()} cores · "
        f"Python {platform.python_version()} · {time.strftime('%Y-%m-%d')}"
    )
    print(f"# {machine}")
    results: dict[str, Any] = {"machine": machine, "arguments": vars(args)}
    for label, classes in (("with classes", True), ("without classes", False)):
        data = scenario(args, classes=classes)
        result = run(data, tmp / label.replace(" ", "-"), args.seed, class_of(args))
        results[label] = result
        print(
            f"\n{data['name']}, {label}: {result['finished']}/{result['vvs']} VVs finished, "
            f"makespan {result['makespan_s']:.0f} s, {result['wall_s']:.0f} s of wall time"
        )
        print("\n".join(table(result, "classes")))
        print("\n".join(table(result)))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(f"\nwritten to {out}")
    if args.keep:
        print(f"the runs' databases: {tmp}/*/simulate.sqlite3")
    else:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
