"""``make bench``: time the VV runtime and a whole paper scenario on this machine.

Prints one line per measurement (median and spread over repeated runs). Not a test: the
numbers depend on the machine; record them with its description in docs/benchmarks.md.
"""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from vvm_worker.runtime import Outcome, StepInput, answer_task, run_step

ROOT = Path(__file__).resolve().parents[1]
CATALOG = [{"name": "GPS", "kind": "gps", "unit": "deg", "params": {}}]
LOOP = """
var gps = VV.sensor.get('GPS');
for (var i = 0; i < %d; i++) {
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48 + i * 1e-5, 12, 20),
                   tolerance: 4, sensors: [gps]}, function (d) { VV.storage.store('pos-' + i, d[0]); });
}
"""


def step(source: str, journal: list[dict] | None = None, applied: int = 0) -> StepInput:
    return StepInput(
        vv_id="bench",
        vv_name="bench",
        source=source,
        seed=1,
        start_ms=0,
        catalog=CATALOG,
        journal=journal or [],
        effects_applied=applied,
    )


def journal_for(tasks: int) -> list[dict]:
    source = LOOP % tasks
    journal: list[dict] = []
    for n in range(tasks):
        result = run_step(step(source, journal, n))
        assert result.outcome is Outcome.SUSPENDED and result.pending is not None
        reading = {"sensor": "GPS", "kind": "gps", "lat": 48.0, "lng": 12.0, "alt": 20.0}
        journal.append(answer_task(result.pending, time_ms=n * 1000, data=[reading]))
    return journal


def measure(name: str, fn: Callable[[], object], repeat: int) -> None:
    fn()  # warm up (V8 initialisation, caches)
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        fn()
        times.append((time.perf_counter() - started) * 1000)
    q = statistics.quantiles(times, n=10) if len(times) >= 10 else [min(times), max(times)]
    print(
        f"{name:<52} median {statistics.median(times):8.2f} ms   p10 {q[0]:8.2f}   p90 {q[-1]:8.2f}   (n={repeat})"
    )


def simulate(scenario: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "CPCC_VAR_DIR": tmp, "CPCC_MEDIA_ROOT": str(Path(tmp) / "media")}
        subprocess.run(
            [sys.executable, "manage.py", "simulate", scenario, "--speed", "0", "--json"],
            cwd=ROOT,
            env=env,
            check=True,
            capture_output=True,
        )


def main() -> None:
    machine = platform.processor() or platform.machine()
    print(f"# {machine} · {os.cpu_count()} cores · Python {platform.python_version()}")
    measure(
        "VV start to first task (new isolate, empty journal)", lambda: run_step(step(LOOP % 1)), 100
    )
    for tasks in (10, 100, 1000):
        journal = journal_for(tasks)
        replay = step(LOOP % tasks, journal, tasks)
        assert run_step(replay).outcome is Outcome.FINISHED
        measure(f"replay of a {tasks}-task journal to the end", lambda r=replay: run_step(r), 20)
    measure(
        "simulate paper-fig3 --speed 0 (whole process)",
        lambda: simulate("examples/scenarios/paper-fig3.json"),
        5,
    )


if __name__ == "__main__":
    main()
