"""The command-line contract of DESIGN.md section 5: simulate and loadscenario."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest
from django.core.management import CommandError, call_command

from accounts.models import Customer, User
from fleet.models import GroundStation, Vehicle
from missions.models import VirtualVehicle, VVStatus
from tests.conftest import SCENARIOS

ROOT = Path(__file__).resolve().parents[2]

# simulate without --keep loads its scenario into a new SQLite database of its own, and with
# --keep into the SQLite file the test names: the second pass's PostgreSQL and Redis change
# nothing in what these tests see.
OWN_SQLITE = pytest.mark.backend_independent(
    "simulate runs on a new SQLite database of its own, or with --keep on the test's SQLite file"
)


def manage(*args: str, tmp: Path, check: bool = True) -> subprocess.CompletedProcess[str]:
    env = {
        **os.environ,
        "CPCC_VAR_DIR": str(tmp / "var"),
        "CPCC_MEDIA_ROOT": str(tmp / "media"),
        "DATABASE_URL": f"sqlite:///{tmp / 'configured.sqlite3'}",
    }
    return subprocess.run(
        [sys.executable, "manage.py", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=check,
        timeout=300,
    )


NUMBER = (int, float)
SHAPE = {
    "": {"makespan_s": NUMBER, "planner": str, "vvs": list, "vehicles": list, "migrations": list},
    "vv": {
        "name": str,
        "customer": str,
        "status": str,
        "error": (str, type(None)),
        "submitted_s": NUMBER,
        "finished_s": (*NUMBER, type(None)),
        "tasks_done": int,
        "storage": dict,
        "tasks": list,
    },
    "task": {
        "position": list,
        "vehicle": (str, type(None)),
        "requested_s": NUMBER,
        "done_s": (*NUMBER, type(None)),
        "status": str,
    },
    "vehicle": {"name": str, "distance_m": NUMBER, "tasks_done": int, "flight_s": NUMBER},
    "migration": {"vv": str, "from": str, "to": str, "at_s": NUMBER},
}


def assert_shape(obj: dict, kind: str) -> None:
    for key, types in SHAPE[kind].items():
        assert key in obj, f"{kind}: {key} missing"
        assert isinstance(obj[key], types) and not isinstance(obj[key], bool), f"{kind}.{key}"


def assert_summary_shape(summary: dict) -> None:
    """The JSON summary contract of DESIGN.md section 5."""
    assert_shape(summary, "")
    for vv in summary["vvs"]:
        assert_shape(vv, "vv")
        assert vv["status"] in {"finished", "failed", "killed", "cancelled"}
        for task in vv["tasks"]:
            assert_shape(task, "task")
            assert len(task["position"]) == 3
    for vehicle in summary["vehicles"]:
        assert_shape(vehicle, "vehicle")
    for migration in summary["migrations"]:
        assert_shape(migration, "migration")


@OWN_SQLITE
@pytest.mark.parametrize("scenario", ["paper-fig2.json", "paper-fig3.json"])
def test_simulate_prints_the_same_json_summary_twice(tmp_path: Path, scenario: str) -> None:
    args = ("simulate", str(SCENARIOS / scenario), "--speed", "0", "--json")
    first = manage(*args, tmp=tmp_path)
    second = manage(*args, tmp=tmp_path)
    last = first.stdout.strip().splitlines()[-1]
    assert last == second.stdout.strip().splitlines()[-1]
    summary = json.loads(last)
    assert_summary_shape(summary)
    assert [v["status"] for v in summary["vvs"]] == ["finished"] * 3
    assert summary["planner"] == "latency"
    # The tasks' waits, from request to reading, summed up: the maximum as well as the mean.
    waits = sorted(t["done_s"] - t["requested_s"] for vv in summary["vvs"] for t in vv["tasks"])
    assert summary["latency"]["tasks"] == len(waits) == 12
    assert summary["latency"]["mean_s"] == pytest.approx(sum(waits) / 12, abs=1e-3)
    assert summary["latency"]["p95_s"] == pytest.approx(waits[11], abs=1e-3)
    assert summary["latency"]["max_s"] == pytest.approx(waits[-1], abs=1e-3)
    # A fresh database each time: the configured one was never created.
    assert not (tmp_path / "configured.sqlite3").exists()


@OWN_SQLITE
def test_simulate_reports_its_own_speed_apart_from_the_summary(tmp_path: Path) -> None:
    speed = re.compile(
        r"^simulated (\d+) tasks, (\d+) migrations and \d+ events in [\d.]+ s of wall time: "
        r"[\d,.]+ tasks/s$",
        re.M,
    )
    args = ("simulate", str(SCENARIOS / "paper-fig2.json"), "--speed", "0")
    shown = manage(*args, tmp=tmp_path)
    line = shown.stdout.strip().splitlines()[-1]
    assert speed.match(line), shown.stdout[-500:]
    as_json = manage(*args, "--json", tmp=tmp_path)
    summary = json.loads(as_json.stdout.strip().splitlines()[-1])
    # With --json the speed goes to stderr: the summary is the same on every run.
    match = speed.search(as_json.stderr)
    assert match is not None, as_json.stderr[-500:]
    assert int(match.group(1)) == sum(vv["tasks_done"] for vv in summary["vvs"]) > 0
    assert int(match.group(2)) == len(summary["migrations"])
    assert "tasks/s" not in as_json.stdout


@OWN_SQLITE
def test_simulate_keep_leaves_the_results_in_the_configured_database(tmp_path: Path) -> None:
    manage(
        "simulate",
        str(SCENARIOS / "paper-fig2.json"),
        "--speed",
        "0",
        "--keep",
        "--planner",
        "nearest",
        tmp=tmp_path,
    )
    out = manage(
        "shell",
        "-c",
        "from missions.models import VirtualVehicle as V; print(sorted(V.objects.values_list('status', flat=True)))",
        tmp=tmp_path,
    )
    assert out.stdout.strip().splitlines()[-1] == "['finished', 'finished', 'finished']"


@OWN_SQLITE
def test_simulate_shows_a_progress_bar_on_a_terminal(tmp_path: Path) -> None:
    main, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 200, 0, 0))
    env = {**os.environ, "CPCC_VAR_DIR": str(tmp_path), "CPCC_MEDIA_ROOT": str(tmp_path / "media")}
    # The terminal's size is what the pseudo-terminal says, as in a shell: not a COLUMNS or
    # LINES of the test run's own (pytest-xdist's workers have COLUMNS=80).
    env.pop("COLUMNS", None)
    env.pop("LINES", None)
    process = subprocess.Popen(
        [
            sys.executable,
            "manage.py",
            "simulate",
            str(SCENARIOS / "paper-fig2.json"),
            "--speed",
            "0",
            "--json",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=child,
    )
    os.close(child)
    try:
        shown, stdout = read_until_closed(process, terminal=main, timeout_s=120)
    finally:
        os.close(main)
        if process.poll() is None:
            process.kill()
        process.wait(timeout=10)
    assert process.returncode == 0
    assert "3/3 VVs ended" in shown.decode(errors="replace")
    assert "12 tasks done" in shown.decode(errors="replace")
    json.loads(stdout.decode().strip().splitlines()[-1])  # stdout still ends with the summary


def read_until_closed(
    process: subprocess.Popen[bytes], *, terminal: int, timeout_s: float
) -> tuple[bytes, bytes]:
    """What a command wrote to its terminal and to its stdout pipe, read until it closed both;
    fails naming what it showed if that takes longer than ``timeout_s`` (a hung command)."""
    assert process.stdout is not None
    pipe = process.stdout.fileno()
    received = {terminal: b"", pipe: b""}
    open_fds = {terminal, pipe}
    deadline = time.monotonic() + timeout_s
    while open_fds:
        left = deadline - time.monotonic()
        ready = select.select(list(open_fds), [], [], max(left, 0))[0]
        if not ready:
            pytest.fail(
                f"simulate did not end within {timeout_s:g} s; its terminal showed "
                f"{received[terminal][-2000:].decode(errors='replace')!r}"
            )
        for fd in ready:
            try:
                chunk = os.read(fd, 65536)
            except OSError:  # the terminal closes when the command exits
                chunk = b""
            if chunk:
                received[fd] += chunk
            else:
                open_fds.discard(fd)
    return received[terminal], received[pipe]


@OWN_SQLITE
def test_simulate_human_output_has_a_table(tmp_path: Path) -> None:
    out = manage("simulate", str(SCENARIOS / "paper-fig2.json"), "--speed", "0", tmp=tmp_path)
    assert "VV 1" in out.stdout and "finished" in out.stdout and "Heli One" in out.stdout


@OWN_SQLITE
def test_simulate_names_an_unknown_key_in_the_scenario(tmp_path: Path) -> None:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    data["vehicles"][0]["max_sped_mps"] = 3
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    out = manage("simulate", str(bad), "--speed", "0", tmp=tmp_path, check=False)
    assert out.returncode != 0
    assert "vehicles[0]" in out.stderr and "unknown key 'max_sped_mps'" in out.stderr


@OWN_SQLITE
def test_simulate_refuses_an_unknown_planner(tmp_path: Path) -> None:
    out = manage(
        "simulate",
        str(SCENARIOS / "paper-fig2.json"),
        "--planner",
        "random",
        tmp=tmp_path,
        check=False,
    )
    assert out.returncode != 0
    assert "invalid choice: 'random'" in out.stderr


@pytest.mark.django_db
def test_loadscenario_loads_fleet_customers_and_vvs_and_is_idempotent(settings, capsys) -> None:
    settings.CPCC_SCENARIO_PASSWORD = "paper-pass-1"
    path = str(SCENARIOS / "paper-fig3.json")
    call_command("loadscenario", path)
    call_command("loadscenario", path, "--no-vvs")
    assert list(GroundStation.objects.values_list("name", flat=True)) == ["GS Base"]
    assert list(Vehicle.objects.values_list("name", flat=True)) == ["Heli One", "Heli Two"]
    assert Customer.objects.count() == 3
    user = User.objects.get(username="customer-a")
    assert user.customer.name == "Customer A"
    assert user.check_password("paper-pass-1")
    assert VirtualVehicle.objects.count() == 3
    assert set(VirtualVehicle.objects.values_list("status", flat=True)) == {VVStatus.QUEUED}
    assert "login customer-a / paper-pass-1" in capsys.readouterr().out


@pytest.mark.django_db
def test_loadscenario_generates_and_prints_a_password(settings, capsys) -> None:
    settings.CPCC_SCENARIO_PASSWORD = ""
    call_command("loadscenario", str(SCENARIOS / "paper-fig2.json"), "--no-vvs")
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if "login customer-b" in x)
    password = line.split(" / ")[1]
    assert User.objects.get(username="customer-b").check_password(password)


@pytest.mark.django_db
def test_loadscenario_names_an_unknown_sensor(tmp_path: Path) -> None:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    data["vehicles"][0]["sensors"].append("Geiger")
    for vv in data["vvs"]:
        vv["program"] = str(SCENARIOS / vv["program"])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(
        CommandError, match=r"vehicles\[0\]\.sensors\[7\]: unknown SDC entry 'Geiger'"
    ):
        call_command("loadscenario", str(bad))
    assert not Vehicle.objects.exists()
