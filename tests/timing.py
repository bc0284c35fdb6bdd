"""The suite's own clock: how long each test took (set-up, call, tear-down) and which processes
it started, so that nobody has to guess where the suite's time goes (docs/testing.md).

Every run writes ``var/test-durations.json`` (``--timing-json PATH`` for another file) and ends
with the suite's total and its slowest directories. Under pytest-xdist each worker reports what
its tests started through the reports' ``user_properties``; the controller adds them up.

``python -m tests.timing [PATH]`` prints the tables of docs/testing.md from such a file.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Generator, Iterable
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_JSON = ROOT / "var" / "test-durations.json"
STARTED = "started"
CPU = "cpu_s"

# What the tests of this process started since the last report (see _recording_popen), and
# the CPU time it and its ended children had used by then.
_started: list[str] = []
_cpu_seen = 0.0
_original_popen_init = subprocess.Popen.__init__


class _Results:
    def __init__(self) -> None:
        # The wall clock, as pytest's reports say when each test started (``report.start``).
        self.started = time.time()
        self.tests: dict[str, dict[str, Any]] = defaultdict(
            lambda: {
                "setup": 0.0,
                "call": 0.0,
                "teardown": 0.0,
                "cpu": 0.0,
                "started": [],
                "outcome": "",
            }
        )


_results: _Results | None = None


def process_name(args: Any) -> str:
    """A short name for a started command: ``rvworker`` for ``python manage.py rvworker ...``,
    ``daphne`` for ``python -m daphne ...``, else the program's file name."""
    words = [str(a) for a in args] if isinstance(args, list | tuple) else str(args).split()
    if not words:
        return "?"
    program = Path(words[0]).name
    if program.startswith("python"):
        rest = words[1:]
        while rest and rest[0].startswith("-") and rest[0] not in ("-m", "-c"):
            rest = rest[1:]
        if rest[:1] == ["-m"] and len(rest) > 1:
            return rest[1] if rest[1] != "pytest" else "pytest"
        if rest and Path(rest[0]).name == "manage.py":
            return rest[1] if len(rest) > 1 else "manage.py"
        if rest and rest[0] == "-c":
            return "python -c"
        return Path(rest[0]).name if rest else program
    if "playwright" in words[0]:
        return "Playwright (Chromium)"
    if program in {"sh", "bash"} and len(words) > 2 and words[1] == "-c":
        return Path(words[2].split()[0]).name
    return program


def _recording_popen(self: subprocess.Popen[Any], args: Any, *more: Any, **kwargs: Any) -> None:
    _started.append(process_name(args))
    _original_popen_init(self, args, *more, **kwargs)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--timing-json",
        default=str(DEFAULT_JSON),
        help="where to write each test's durations and started processes (JSON)",
    )


def pytest_configure(config: pytest.Config) -> None:
    global _results
    subprocess.Popen.__init__ = _recording_popen  # type: ignore[method-assign]
    _results = _Results()


def pytest_unconfigure(config: pytest.Config) -> None:
    subprocess.Popen.__init__ = _original_popen_init  # type: ignore[method-assign]


def cpu_used() -> float:
    """CPU seconds of this process and of its children that have ended (a worker process a
    test stopped counts; one still running does not)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def pytest_runtest_logstart() -> None:
    global _cpu_seen
    _cpu_seen = cpu_used()
    _started.clear()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator:
    global _cpu_seen
    outcome = yield
    report = outcome.get_result()
    now = cpu_used()
    report.user_properties.append((CPU, round(now - _cpu_seen, 3)))
    _cpu_seen = now
    if _started:
        report.user_properties.append((STARTED, list(_started)))
        _started.clear()


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if _results is None:
        return
    test = _results.tests[test_id(report)]
    test[report.when] = round(test[report.when] + report.duration, 3)
    for name, value in report.user_properties:
        if name == STARTED:
            test["started"].extend(value)
        elif name == CPU:
            test["cpu"] = round(test["cpu"] + value, 3)
    if report.when == "setup":
        # When it started, in seconds from the run's start, and on which worker: the run's
        # timeline (pytest-xdist's controller says which worker sent the report).
        test["start_s"] = round(report.start - _results.started, 1)
        node = getattr(report, "node", None)
        test["worker"] = node.gateway.id if node is not None else "main"
    if report.when == "call" or report.outcome != "passed":
        test["outcome"] = report.outcome


def test_id(report: pytest.TestReport) -> str:
    """The test's node id, with the name of a test that shares its node id with others
    (schemathesis makes one test per API operation, all with the function's node id)."""
    name = report.location[2].rsplit(".", 1)[-1]
    if report.nodeid.endswith(name):
        return report.nodeid
    return f"{report.nodeid.rsplit('::', 1)[0]}::{name}"


def directory(nodeid: str) -> str:
    return str(Path(nodeid.split("::", 1)[0]).parent)


def total(test: dict[str, Any]) -> float:
    return float(test["setup"] + test["call"] + test["teardown"])


def by_directory(tests: dict[str, dict[str, Any]]) -> list[tuple[str, int, float]]:
    """(directory, tests, seconds) for every directory, slowest first."""
    counts: dict[str, int] = defaultdict(int)
    seconds: dict[str, float] = defaultdict(float)
    for nodeid, test in tests.items():
        counts[directory(nodeid)] += 1
        seconds[directory(nodeid)] += total(test)
    return sorted(((d, counts[d], seconds[d]) for d in counts), key=lambda row: -row[2])


def minutes(seconds: float) -> str:
    return f"{int(seconds // 60)} min {seconds % 60:04.1f} s"


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    if hasattr(config, "workerinput") or _results is None or not _results.tests:
        return
    wall = time.time() - _results.started
    tests = _results.tests
    summed = sum(total(t) for t in tests.values())
    workers = getattr(config.option, "numprocesses", None) or 1
    path = Path(config.getoption("--timing-json"))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps(
            {
                "wall_s": round(wall, 1),
                "workers": workers,
                "backend": _backend(),
                "python": sys.version.split()[0],
                "tests": tests,
            },
            indent=1,
        )
    )
    write = terminalreporter.write_line
    terminalreporter.section("the suite's time (docs/testing.md says how to read it)")
    write(
        f"{len(tests)} tests in {minutes(wall)} of wall time on {workers} worker(s), "
        f"{minutes(summed)} of test time; each test's figures in {_shown(path)}"
    )
    for name, count, seconds in by_directory(tests)[:6]:
        write(f"  {seconds:7.1f} s  {count:5d} tests  {name}")


def _shown(path: Path) -> str:
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def _backend() -> str:
    database = (
        "PostgreSQL" if os.environ.get("DATABASE_URL", "").startswith("postgres") else "SQLite"
    )
    redis = "Redis server" if os.environ.get("REDIS_URL") else "embedded Redis"
    return f"{database}, {redis}"


# --- the tables of docs/testing.md -------------------------------------------------------


def started_summary(names: Iterable[str]) -> str:
    counts: dict[str, int] = defaultdict(int)
    for name in names:
        counts[name] += 1
    return ", ".join(f"{n} x{c}" if c > 1 else n for n, c in sorted(counts.items())) or "-"


def tables(data: dict[str, Any], slowest: int = 40) -> str:
    tests = data["tests"]
    lines = [
        f"{len(tests)} tests, {minutes(data['wall_s'])} of wall time on {data['workers']} "
        f"worker(s), {data['backend']}.",
        "",
        "| directory | tests | seconds | share |",
        "| --- | ---: | ---: | ---: |",
    ]
    summed = sum(total(t) for t in tests.values()) or 1.0
    for name, count, seconds in by_directory(tests):
        lines.append(f"| `{name}` | {count} | {seconds:.1f} | {100 * seconds / summed:.1f} % |")
    lines += [
        "",
        "| test | seconds (set-up + call + tear-down) | what it starts |",
        "| --- | ---: | --- |",
    ]
    ranked = sorted(tests.items(), key=lambda item: -total(item[1]))[:slowest]
    for nodeid, test in ranked:
        parts = f"{test['setup']:.1f} + {test['call']:.1f} + {test['teardown']:.1f}"
        lines.append(
            f"| `{nodeid}` | {total(test):.1f} ({parts}) | {started_summary(test['started'])} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    source = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_JSON
    print(tables(json.loads(source.read_text())))
