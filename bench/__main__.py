"""``make bench``: time the VV runtime and whole scenarios on this machine.

Prints one line per measurement: the median and the 10th and 90th percentiles over repeated
runs after a warm-up. Not a test: the figures depend on the machine; record them with its
description and the date in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from fleet.geo import Position
from fleet.simulation import SensorSpec, render_camera
from vvm_worker.runtime import (
    Outcome,
    Runtime,
    StepInput,
    TaskRequest,
    answer_task,
    run_step,
)
from vvm_worker.scenario_gen import grid_box, grid_scenario, original_style_program

ROOT = Path(__file__).resolve().parents[1]
CATALOG = [{"name": "GPS", "kind": "gps", "unit": "deg", "params": {}}]
BOX = grid_box(rows=3, cols=3, cell_m=50)


def program(tasks: int) -> str:
    return original_style_program(box=BOX, tasks=tasks)


def step_input(
    source: str, journal: Sequence[Mapping[str, Any] | str], applied: int, vv_id: str = "bench"
) -> StepInput:
    return StepInput(
        vv_id=vv_id,
        vv_name=vv_id,
        source=source,
        seed=1,
        start_ms=0,
        catalog=CATALOG,
        journal=journal,
        effects_applied=applied,
    )


def reading(task: TaskRequest) -> dict[str, Any]:
    return {"sensor": "GPS", "kind": "gps", "time": "2025-01-01T00:00:00.000Z",
            "position": {"lat": task.lat, "lng": task.lng, "alt": task.alt},
            "lat": task.lat, "lng": task.lng, "alt": task.alt, "satellites": 9, "hdop": 0.8}  # fmt: skip


def drive(
    runtime: Runtime, source: str, vv_id: str = "bench"
) -> tuple[list[float], list[dict[str, Any]]]:
    """Run a VV to its end in one runtime; the duration of every step, in ms, and its journal."""
    journal: list[dict[str, Any]] = []
    applied = 0
    times = []
    while True:
        started = time.perf_counter()
        result = runtime.step(step_input(source, journal, applied, vv_id))
        times.append((time.perf_counter() - started) * 1000)
        applied = result.effects_total
        if result.outcome is not Outcome.SUSPENDED:
            assert result.outcome is Outcome.FINISHED, result.error
            return times, journal
        assert result.pending is not None
        journal.append(
            answer_task(
                result.pending, time_ms=len(journal) * 1000, data=[reading(result.pending.tasks[0])]
            )
        )


def show(name: str, times: list[float], unit: str = "ms") -> None:
    q = statistics.quantiles(times, n=10) if len(times) >= 10 else [min(times), max(times)]
    print(
        f"{name:<62} median {statistics.median(times):9.2f} {unit}   "
        f"p10 {q[0]:9.2f}   p90 {q[-1]:9.2f}   (n={len(times)})",
        flush=True,
    )


def repeat(fn: Callable[[], object], times: int, pause_s: float = 0.0) -> list[float]:
    fn()  # warm up
    out = []
    for _ in range(times):
        if pause_s:
            time.sleep(pause_s)  # as between two VVs arriving: the isolate pool refills
        started = time.perf_counter()
        fn()
        out.append((time.perf_counter() - started) * 1000)
    return out


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def simulate(data_or_path: dict[str, Any] | str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = data_or_path
        if isinstance(data_or_path, dict):
            path = str(Path(tmp) / "scenario.json")
            Path(path).write_text(json.dumps(data_or_path))
        env = {**os.environ, "CPCC_VAR_DIR": tmp, "CPCC_MEDIA_ROOT": str(Path(tmp) / "media")}
        subprocess.run(
            [sys.executable, "manage.py", "simulate", str(path), "--speed", "0", "--json"],
            cwd=ROOT,
            env=env,
            check=True,
            capture_output=True,
        )


def cameras() -> None:
    """One 640x480 PNG per view of the camera, as an RV renders it at every camera reading
    (a per-pixel Python loop would take seconds; the target is well under 100 ms)."""
    position = Position(47.0707, 15.4395, 60.0)
    for view in ("front", "belly", "fpv"):
        sensor = SensorSpec(
            "Camera 640x480", "camera", params={"width": 640, "height": 480, "view": view}
        )
        show(
            f"camera picture 640x480, {view} view (render and PNG encoding)",
            repeat(functools.partial(render_camera, sensor, position, 0.0, seed=1), 20),
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--long", action="store_true", help="also run a 5,000-task VV (minutes)")
    args = parser.parse_args()
    machine = platform.processor() or platform.machine()
    print(f"# {machine} · {os.cpu_count()} cores · Python {platform.python_version()}")

    one = program(1)
    show(
        "VV start to first task (new context from the pool)",
        repeat(lambda: run_step(step_input(one, [], 0)), 100, pause_s=0.02),
    )

    runtime = Runtime()
    times, _ = drive(runtime, program(50))
    show("per step, 50-task original-style VV (warm context)", times[1:])
    times, journal = drive(runtime, program(1000))
    show("per step, 1,000-task original-style VV (warm context)", times[1:])
    show("  its last 100 steps (journal of 900-1,000 answers)", times[-100:])

    # As a host reads it from the database: each entry as JSON text.
    replay = step_input(program(1000), [json.dumps(e) for e in journal], 1000)
    assert run_step(replay).outcome is Outcome.FINISHED
    show(
        "replay of a 1,000-task journal in a new context (arrival)",
        repeat(lambda: run_step(replay), 20, pause_s=0.02),
    )
    for n in (10, 100):
        _, small = drive(Runtime(), program(n))
        fixed = step_input(program(n), [json.dumps(e) for e in small], n)
        show(
            f"replay of a {n}-task journal in a new context",
            repeat(functools.partial(run_step, fixed), 20, pause_s=0.02),
        )

    idle = Runtime(max_contexts=1000)
    before = rss_bytes()
    heaps = []
    for k in range(50):
        result = idle.step(step_input(program(50), [], 0, vv_id=f"idle-{k}"))
        assert result.outcome is Outcome.SUSPENDED
        ctx = idle.context(f"idle-{k}")
        assert ctx is not None
        heaps.append(ctx.heap_bytes() / 1024 / 1024)
    per_vv = (rss_bytes() - before) / 50 / 1024 / 1024
    print(f"{'memory per idle VV (warm context), resident':<62} {per_vv:9.2f} MB   (50 VVs)")
    show("  V8 heap used per idle VV", heaps, unit="MB")
    idle.close()

    cameras()

    show(
        "simulate paper-fig3 --speed 0 (whole process)",
        repeat(lambda: simulate("examples/scenarios/paper-fig3.json"), 5),
    )
    grid = grid_scenario(rows=3, cols=3, cell_m=50, customers=2)
    grid["vvs"] = [
        {"customer": f"Customer {c}", "name": "demo", "source": program(50), "copies": 2}
        for c in (1, 2)
    ]
    show("simulate 4 x 50-task VVs on a 3x3 grid of 50 m cells", repeat(lambda: simulate(grid), 3))

    if args.long:
        started = time.perf_counter()
        times, _ = drive(Runtime(), program(5000))
        total = time.perf_counter() - started
        print(f"{'5,000-task VV, all steps in one warm context':<62} {total:9.1f} s total")
        show("  its steps 41-60 (journal of 40-59 answers)", times[40:60])
        show("  its last 100 steps", times[-100:])


if __name__ == "__main__":
    main()
